"""Parameterized motion on real data, built through the search pipeline (KG04 §4.4 on CMU subject 16).

Two motion spaces, each made exactly as ``motionweb parameterize`` makes it: an index of the
trials (``motionweb index``), a query segment, the search (KG04 §3.3), the examples registered
(walks: KG04 §4.1 along the match graph; jumps: keyed by each match's detected flight phase,
``tasks/flights.py``), 1000 samples (§4.2), stored and loaded back:

* walk: the subject-16 walks and veers, query 16_15 1.0-2.2 s (one stride), final root position;
* forward jump: the subject-16 jumps, query 16_07 1.5-2.9 s (crouch, flight, landing), landing
  position (final root on the ground).

Printed per space: the examples and the search's ε, leave-one-out error (each example's
parameters synthesized from a space of the others; KG04 §4.4 measures its accuracy the same
way), targets near samples, and foot skate (mean horizontal ankle speed on planted frames, cm/s)
of the examples against blends before and after the plants are held.

Run from the repo root: ``python -m bench.parameterize_cmu`` (needs the mocap folder, see
``store.datasets.mocap_root``; builds a temporary index of 25 trials: minutes on a busy machine,
most of it Prefect starting).
"""

from __future__ import annotations

import os
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from motionweb.store.datasets import mocap_root
from motionweb.store.generations import load_generation
from motionweb.store.kinematics import forward_kinematics_of
from motionweb.store.zarr_store import MotionStore
from motionweb.tasks.blend import BlendParams, blend, detect_plants, foot_skate
from motionweb.tasks.parameterize import leave_one_out

WALKS = (11, 12, 13, 14, 15, 16, 21, 22, 23, 24, 25, 26, 31, 32, 47, 58)
JUMPS = (1, 2, 3, 4, 5, 6, 7, 9, 10)
QUERIES = {  # label: (trials, query clip, start s, end s, quantile, parameter)
    "walk (subject 16 walks and veers, one stride; final root)": (WALKS, "16_15", 1.0, 2.2, 0.5, "final_root"),
    "forward jump (subject 16 jumps, crouch to landing; landing position)": (JUMPS, "16_07", 1.5, 2.9, 0.7,
                                                                            "final_root"),
}


def corpus(folder: Path, trials) -> None:
    """A corpus folder of links to the subject's skeleton and the trials."""
    src = mocap_root() / "cmu" / "asf_amc" / "16"
    folder.mkdir(parents=True)
    (folder / "16.asf").symlink_to(src / "16.asf")
    for t in trials:
        (folder / f"16_{t:02d}.amc").symlink_to(src / f"16_{t:02d}.amc")
    from motionweb.store.catalog import UNCATEGORIZED, scan_corpus

    from bench.corpus import check_corpus  # stops unless every trial loads (with its skeleton)

    check_corpus(folder, scan_corpus(folder), {f"16_{t:02d}.amc": UNCATEGORIZED for t in trials}, 0)


def example_skates(st, bcfg: BlendParams) -> list[float]:
    """Foot skate of every example over its own registered segment at its own fps (cm/s)."""
    from motionweb.flows.query import indexed_config, load_indexed_clip

    ex, reg_rate = st.space.examples, st.space.examples.rate
    feet = [ex.legs["left"][2], ex.legs["right"][2]]
    out = []
    store = MotionStore(st.info["store"], read_only=True)
    gen = load_generation(store, st.info["generation"])
    gen_cfg = indexed_config(gen)
    recs = {c["path"]: c for c in gen.clips}
    for clip, (a, b) in zip(st.info["clips"], st.info["segments"], strict=True):
        m = load_indexed_clip(gen_cfg, recs[clip])
        f0, f1 = int(a * m.fps / reg_rate), int(b * m.fps / reg_rate)
        mm = replace(m, skeleton=ex.skeleton, root_positions=m.root_positions[f0:f1 + 1] * m.metres(),
                     rotations=m.rotations[f0:f1 + 1], translations={})
        ank = forward_kinematics_of(mm, feet)[0][:, feet]
        out.append(foot_skate(ank, detect_plants(ank, m.fps, bcfg), m.fps))
    return out


def report(label: str, cfg, request) -> None:
    from motionweb.flows.space import load_space, parameterize, plan_space

    t = time.perf_counter()
    plan_space(cfg, request)
    res = parameterize(cfg, request)
    st = load_space(cfg, res["id"])
    built = time.perf_counter() - t
    sp, ex = st.space, st.space.examples
    p = sp.example_params
    print(f"\n{label}: query {request.clip} {request.start:g}-{request.end:g} s, quantile {request.quantile} "
          f"(ε = {res['epsilon']:.4g}); {ex.n} examples ({st.info['registration']} registration), {len(sp.params)} samples; "
          f"built in {built:.0f} s")
    print(f"  examples' final root (x, z) from {p.min(0).round(2)} to {p.max(0).round(2)} m")
    loo = leave_one_out(sp.fn, ex, sp.cfg)
    print(f"  leave-one-out error (cm): median {100 * np.median(loo):.1f}, mean {100 * loo.mean():.1f}, "
          f"max {100 * loo.max():.1f}")
    rng = np.random.default_rng(0)
    bcfg = BlendParams.model_validate(st.info["blend"])
    res_b = []
    for tgt in sp.params[rng.choice(np.arange(ex.n, len(sp.params)), 10)] + 0.005:
        s = sp.synthesize(tgt)
        r = blend(ex, s.weights, fps=st.fps, cfg=bcfg)
        res_b.append((s.error, r.skate_raw, r.skate, r.ik_miss))
    res_b = np.array(res_b)
    skates = example_skates(st, bcfg)
    print(f"  10 targets 0.5 cm off samples: error mean {100 * res_b[:, 0].mean():.2f} cm, max {100 * res_b[:, 0].max():.2f}")
    print(f"  foot skate (cm/s, planted frames): examples mean {np.mean(skates):.2f} "
          f"({min(skates):.2f}-{max(skates):.2f}); blends before IK {res_b[:, 1].mean():.2f}, after "
          f"{res_b[:, 2].mean():.2f} (max {res_b[:, 2].max():.2f}); worst IK miss {1000 * res_b[:, 3].max():.1f} mm")


def main() -> None:
    # before Prefect is imported: a patient start of its ephemeral server on a busy machine, terse logs
    os.environ.setdefault("PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS", "600")
    os.environ.setdefault("PREFECT_LOGGING_LEVEL", "WARNING")
    os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
    from motionweb.flows.commands.cli import app
    from motionweb.flows.commands.requests import SpaceRequest
    from motionweb.flows.config import load_config

    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    with tempfile.TemporaryDirectory() as tmp:
        for k, (label, (trials, clip, a, b, q, param)) in enumerate(QUERIES.items()):
            root = Path(tmp) / f"space{k}"
            corpus(root / "corpus", trials)
            cfg_path = root / "config.yaml"
            cfg_path.write_text("corpus: {path: corpus}\nstore: {path: store}\noutput: out\n")
            app(["index", str(cfg_path), "--no-progress"], standalone_mode=False)
            cfg = load_config(cfg_path)
            report(label, cfg, SpaceRequest(clip=clip, start=a, end=b, param=param, quantile=q))


if __name__ == "__main__":
    main()
