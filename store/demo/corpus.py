"""A seeded, procedural, synthetic demo corpus: the project's own data (no downloads).

Every clip is built from a plan by the rig (`rig.py`: analytic two-bone IK for legs and arms) from a
per-category generator (`clips.py`), so the ground truth (foot stance intervals, exact ballistic
flights, effector targets at apex frames) holds by construction. This module places a clip in the
world, writes its truth and the corpus: :data:`CATEGORIES`, :func:`generate_clip`,
:func:`walk_then_jump`, :func:`seeded_rng`, :func:`clip_from_rng`,
:func:`write_clip`, :func:`truth_json`, :func:`write_demo_corpus`.
"""

from __future__ import annotations

import json
import math
import zlib
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from motionweb.store.bvh import write_bvh
from motionweb.store.demo.clips import GENERATORS, apply_jump, plan_jump, walk_gait
from motionweb.store.demo.rig import (
    SIDES,
    UNIT_Y,
    ClipSpec,
    FootTrack,
    G,
    Plant,
    Rig,
    build_motion,
    foot_track,
    frame_times,
    humanoid_skeleton,
    level_head,
    max_root_heights,
    neutral_plan,
    qaxis,
    qypr,
    rot_y,
    smooth,
)
from motionweb.store.kinematics import heading_angle, quat_mul, quat_rotate
from motionweb.store.motion import Motion

#: the clip categories of the demo corpus.
CATEGORIES: tuple[str, ...] = ("walk", "run", "jump", "kick", "punch", "reach", "hop", "sit", "idle")

# --------------------------------------------------------------------------------------------------
# putting it together


def seeded_rng(category: str, variant: int, seed: int) -> np.random.Generator:
    """The generator of one clip: seeded by (seed, CRC-32 of ``category``, variant), so each clip's
    draws are independent of every other clip's and of the order clips are made in."""
    return np.random.default_rng([int(seed) & 0xFFFFFFFF, zlib.crc32(category.encode()), int(variant)])


def _frame_interval(t0: float, t1: float, fps: float, n: int) -> tuple[int, int]:
    return int(np.clip(round(t0 * fps), 0, n - 1)), int(np.clip(round(t1 * fps), 0, n - 1))


def _finish(rig: Rig, spec: ClipSpec, category: str, variant: int, seed: int, fps: float,
            rng: np.random.Generator, name: str) -> tuple[Motion, dict[str, Any]]:
    """Place the clip in the world (random start heading and position), build it, write the truth."""
    motion, ik_miss = build_motion(rig, spec.plan, fps, name)
    yaw0 = float(rng.uniform(-np.pi, np.pi))
    shift = np.array([rng.uniform(-2.0, 2.0), 0.0, rng.uniform(-2.0, 2.0)])
    q0 = qaxis(UNIT_Y, np.array(yaw0))
    root = quat_rotate(q0, motion.root_positions) + shift
    rots = motion.rotations.copy()
    rots[:, 0] = quat_mul(q0, rots[:, 0])
    motion = replace(motion, root_positions=root, rotations=rots)
    n = motion.n_frames
    h0 = float(heading_angle(rots[0, 0]))
    origin = root[0] * np.array([1.0, 0.0, 1.0])

    def to_start(p: np.ndarray) -> np.ndarray:
        return rot_y(-h0, p - origin)

    actions = []
    for a in spec.actions:
        s, e = _frame_interval(a["t0"], a["t1"], fps, n)
        item = {"label": a["label"], "start_s": a["t0"], "end_s": a["t1"], "start_frame": s, "end_frame": e}
        if "apex" in a:
            item["apex_s"] = a["apex"]
            item["apex_frame"] = round(float(a["apex"]) * fps)
        actions.append(item)
    targets = []
    for tg in spec.targets:
        world = quat_rotate(q0, tg["local"]) + shift
        targets.append({"name": tg["name"], "effector": tg["effector"], "apex_s": tg["t"],
                        "apex_frame": round(float(tg["t"]) * fps), "position": to_start(world), "world": world})
    flights = []
    for a, b in spec.flights:
        s, e = math.ceil(a * fps - 1e-9), math.floor(b * fps + 1e-9)
        if s <= e and s < n and e >= 0:
            flights.append({"start_s": a, "end_s": b, "start_frame": max(s, 0), "end_frame": min(e, n - 1),
                            "duration": b - a, "ballistic": category in _BALLISTIC})
    contacts: dict[str, list[list[int]]] = {}
    heel: dict[str, list[list[int]]] = {}
    for side in SIDES:
        contacts[side], heel[side] = [], []
        for p in spec.plants[side]:
            s, e = max(math.ceil(p.t_on * fps - 1e-9), 0), min(math.floor(p.t_off * fps + 1e-9), n - 1)
            if s <= e:
                contacts[side].append([s, e])
                th = p.t_off if p.t_heel is None else p.t_heel
                eh = min(math.floor(th * fps + 1e-9), n - 1)
                if s <= eh:
                    heel[side].append([s, eh])
    truth = {
        "category": category, "variant": variant, "seed": seed, "fps": fps, "unit": "m", "up": "y",
        "frames": n, "duration": motion.duration, "gravity": G,
        "actions": actions, "targets": targets, "flight": flights,
        "contacts": contacts, "heel_contacts": heel,
        "start": {"yaw_deg": math.degrees(h0), "position": origin},
        "ik_max_miss_m": ik_miss,
        "params": spec.params,
    }
    return motion, truth


#: categories whose flights are exact parabolas under G (runs only approximate them).
_BALLISTIC = ("jump", "hop", "walk_then_jump")


def generate_clip(category: str, variant: int, seed: int, fps: float = 60.0) -> tuple[Motion, dict[str, Any]]:
    """One synthetic clip of ``category`` and its ground truth; deterministic in (category, variant,
    seed, fps). Targets are in the clip's start heading frame (origin: root at frame 0 on the
    ground, axes turned by the heading at frame 0); ``world`` gives them in the file's frame."""
    return clip_from_rng(category, variant, seeded_rng(category, variant, seed), seed, fps)


def clip_from_rng(category: str, variant: int, rng: np.random.Generator, seed: int = 0, fps: float = 60.0,
                  name: str | None = None) -> tuple[Motion, dict[str, Any]]:
    """One synthetic clip of ``category`` drawn from ``rng`` (``variant`` picks the generator's
    style: speeds, sides, heights; ``seed`` is only recorded in the truth): what
    :func:`generate_clip` makes with its own seeded generator, for callers that seed clips
    otherwise (``takes.py``). Cost O(frames · joints)."""
    if category not in GENERATORS:
        raise ValueError(f"unknown category {category!r}; expected one of {', '.join(CATEGORIES)}")
    rig = Rig.from_skeleton(humanoid_skeleton())
    spec = GENERATORS[category](rig, variant, rng, fps)
    return _finish(rig, spec, category, variant, seed, fps, rng, name or f"{category}_{variant:02d}")


def walk_then_jump(seed: int = 0, fps: float = 60.0) -> tuple[Motion, dict[str, Any]]:
    """About 2-3 s of straight walking, a stop, then a forward jump with an exact ballistic flight
    of at least 0.5 s and a landing (the guided-warp test clip)."""
    rig = Rig.from_skeleton(humanoid_skeleton())
    rng = seeded_rng("walk_then_jump", 0, seed)
    gait = replace(walk_gait(1, rng), turn=0.0)
    plants = gait.plants(rig, 0.0, 8.0)
    t_min = 1.9 + 0.3 * rng.uniform(0, 1)
    _, side_a, ia = min((p.t_on, s, i) for s in SIDES for i, p in enumerate(plants[s]) if p.t_on >= t_min)
    side_b = "right" if side_a == "left" else "left"
    a_plant = plants[side_a][ia]
    t_a = a_plant.t_on
    b_list = [p for p in plants[side_b] if p.t_on < t_a]
    b_next = next(p for p in plants[side_b] if p.t_on > t_a)
    b_final = Plant(t_on=b_next.t_on, t_off=100.0, yaw=b_next.yaw,
                    ankle=np.array([-a_plant.ankle[0], rig.ankle_height, a_plant.ankle[2]]))
    a_final = replace(a_plant, t_off=100.0, t_heel=None, heel_pitch=0.0)
    stop_plants = {side_a: [p for p in plants[side_a] if p.t_on < t_a] + [a_final], side_b: b_list + [b_final]}
    ground_a, _, _ = gait.root(np.array([t_a]))
    z_stop = a_plant.ankle[2] + 0.05
    t_d = 2.0 * (z_stop - ground_a[0, 2]) / gait.speed
    t_ready = max(t_a + t_d, b_final.t_on) + 0.25
    stance = {side_a: a_final, side_b: b_final}
    ready_y = rig.stand_height - 0.03
    jump = plan_jump(rig, t_ready, np.array([0.0, ready_y, z_stop]), stance, 0.42 + 0.02 * rng.uniform(0, 1),
                     0.5 + 0.2 * rng.uniform(0, 1), gait.width)
    all_plants = {s: stop_plants[s][:-1] + jump.plants[s] for s in SIDES}
    t = frame_times(jump.t_end + 0.6, fps)
    feet = {s: foot_track(rig, t, all_plants[s], gait.lift) for s in SIDES}
    plan = neutral_plan(rig, t, feet)
    # walking root, then an eased stop (velocity v(1 - smooth(u)) along +Z), then the jump
    ground, bob, rot = gait.root(t)
    pre = t <= t_a
    lim = max_root_heights(rig, ground[pre], rot[pre], {s: FootTrack(f.ankle[pre], f.yaw[pre], f.pitch[pre],
                                                                       f.stance[pre]) for s, f in feet.items()},
                            0.975 * rig.leg)
    base = float(min(np.min(lim - bob[pre]), rig.stand_height - 0.01))
    u = np.clip((t - t_a) / t_d, 0.0, 1.0)
    s_u = smooth(u)
    fade = 1.0 - s_u
    ga, _, _ = gait.root(np.array([t_a]))
    z = np.where(pre, ground[:, 2], ga[0, 2] + gait.speed * t_d * (u - u ** 3 + 0.5 * u ** 4))
    x = np.where(pre, ground[:, 0], ground[:, 0] * fade)
    y = np.where(pre, base + bob, (base + bob) * fade + ready_y * s_u)
    plan.root_pos = np.stack([x, y, z], -1)
    ph = gait.cycle(t)
    wfade = np.where(pre, 1.0, fade)
    plan.root_rot = qypr(-gait.pelvis_yaw * np.cos(ph) * wfade, gait.lean * 0.5 * wfade)
    gait.upper(plan, t)
    plan.spine *= wfade[:, None]
    for s in SIDES:
        plan.arms[s] = plan.arms[s] * wfade[:, None] + np.array([0.07, math.radians(6.0), 0.2]) * (1 - wfade[:, None])
    level_head(plan, gait.lean * 0.5 * wfade)
    apply_jump(rig, plan, jump, weight=(t >= t_ready).astype(np.float64))
    actions = [{"label": "walk", "t0": 0.0, "t1": t_a}, {"label": "stop", "t0": t_a, "t1": t_ready}, *jump.actions,
               {"label": "stand", "t0": jump.t_end, "t1": float(t[-1])}]
    flights = [(jump.t0, jump.t1)]
    params = {"speed": gait.speed, "cadence": gait.cadence, "walk_root_height": base, **jump.params}
    spec = ClipSpec(plan, actions, [], flights, all_plants, params)
    return _finish(rig, spec, "walk_then_jump", 0, seed, fps, rng, "walk_then_jump")



# --------------------------------------------------------------------------------------------------
# writing


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        v = round(float(x), 6)
        return 0.0 if v == 0 else v
    return x


def truth_json(truth: dict[str, Any]) -> str:
    """Canonical JSON text of a ground-truth dict (sorted keys, floats rounded to 6 decimals)."""
    return json.dumps(_jsonable(truth), sort_keys=True, indent=1) + "\n"


def write_clip(motion: Motion, truth: dict[str, Any], stem: Path) -> Path:
    """Write ``<stem>.bvh`` and ``<stem>.json``; returns the BVH path."""
    stem.parent.mkdir(parents=True, exist_ok=True)
    bvh = stem.with_suffix(".bvh")
    write_bvh(motion, bvh)
    stem.with_suffix(".json").write_text(truth_json(truth))
    return bvh


def write_demo_corpus(out_dir: str | Path, seed: int = 7, variants_per_category: int = 3,
                      fps: float = 60.0, variants: dict[str, int] | None = None) -> list[Path]:
    """Write ``<out_dir>/<category>/<category>_<variant:02d>.bvh`` and ``.json`` ground truth for
    every category (``variants[category]`` clips where given, else ``variants_per_category``);
    returns the BVH paths. Same inputs give the same bytes."""
    unknown = sorted(set(variants or {}) - set(CATEGORIES))
    if unknown:
        raise ValueError(f"demo variants: unknown categories {', '.join(unknown)}; expected {', '.join(CATEGORIES)}")
    out = Path(out_dir)
    paths = []
    for cat in CATEGORIES:
        for v in range((variants or {}).get(cat, variants_per_category)):
            motion, truth = generate_clip(cat, v, seed, fps)
            paths.append(write_clip(motion, truth, out / cat / f"{cat}_{v:02d}"))
    return paths
