"""Planted corpora for search and registration tests (KG04 §3.3-4.1 ground truth).

:func:`planted_corpus`: the kick action of a synthetic kick clip is the query; copies of its clip
are planted inside clips of other categories, each copy time-warped by a known random non-linear
warp (local speed 0.7x-1.5x), turned to a random heading, with small pose noise
(``store.demo.perturb.pose_noise``).
:func:`variant_chain`: progressively more different variants of the query clip (each close to the
previous one, the last far from the query), for tiered search; :func:`near_copy_chain` adds a near
copy of the query and a variant bent the other way. :class:`CorpusWebs` builds every
web of a corpus on demand (features + coarse-to-fine webs, no store, no Prefect).

Everything is generated at the web rate (30 Hz), so frames of clips are frames of the webs.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field, replace

import numpy as np
from motionweb.store.demo.corpus import generate_clip
from motionweb.store.demo.perturb import pose_noise, random_warp, time_warp_clip
from motionweb.store.kinematics import quat_from_axis_angle, quat_from_euler, quat_mul, quat_rotate
from motionweb.store.motion import Motion
from motionweb.store.web import MatchWeb, transpose
from motionweb.tasks.features import FeatureParams, clip_features, point_weights
from motionweb.tasks.matchgraph import Segment
from motionweb.tasks.matchweb.build import build_web
from motionweb.tasks.matchweb.params import MatchWebParams

RATE = 30.0
DISTRACTORS = ("walk", "run", "jump", "punch", "reach", "hop", "sit", "idle")


@dataclass
class PlantedCorpus:
    """Clips by key (``<category>/<name>``) at ``rate``, the query segment and the ground truth.

    ``expected[key]``: the segment a correct search returns in each planted clip.
    ``warps[key]``: for every frame of that clip, the frame of the query clip it shows
    (fractional; NaN outside the planted copy) — source frame as a function of copy frame.
    """

    rate: float
    query: Segment
    clips: dict[str, Motion]
    categories: dict[str, str]
    expected: dict[str, Segment] = field(default_factory=dict)
    warps: dict[str, np.ndarray] = field(default_factory=dict)


def _turned(motion: Motion, yaw: float, shift: np.ndarray) -> Motion:
    """The clip turned about the vertical axis by ``yaw`` and moved by ``shift`` (a rigid 2-D motion)."""
    q = quat_from_axis_angle(np.array([0.0, 1.0, 0.0]), np.array(yaw))
    rot = motion.rotations.copy()
    rot[:, 0] = quat_mul(q, rot[:, 0])
    return replace(motion, root_positions=quat_rotate(q, motion.root_positions) + shift, rotations=rot)


def _concat(parts: list[Motion], name: str) -> Motion:
    return Motion(parts[0].skeleton, parts[0].fps, np.concatenate([p.root_positions for p in parts]),
                  np.concatenate([p.rotations for p in parts]), name=name, unit=parts[0].unit,
                  scale_to_m=parts[0].scale_to_m)


def _query_clip(seed: int) -> tuple[Motion, Segment]:
    motion, truth = generate_clip("kick", 0, seed, fps=RATE)
    kick = next(a for a in truth["actions"] if a["label"] == "kick")
    return motion, Segment("kick/query", int(kick["start_frame"]), int(kick["end_frame"]))


def planted_corpus(seed: int = 0, n_copies: int = 20, noise_deg: float = 1.0, margin_s: float = 0.6,
                   distractors: tuple[str, ...] = DISTRACTORS) -> PlantedCorpus:
    """The query clip, ``n_copies`` warped noisy copies of its kick action (± ``margin_s``) planted
    between pieces of other categories' clips, and one whole clip of each distractor category."""
    rng = np.random.default_rng(seed)
    whole, query = _query_clip(seed)
    pc = PlantedCorpus(RATE, query, {query.clip: whole}, {query.clip: "kick"})
    hosts = [generate_clip(c, v, seed + 1, fps=RATE)[0] for v in range(2) for c in distractors]
    lo = max(0, query.start - round(margin_s * RATE))
    source = sample(whole, lo, min(whole.n_frames, query.end + round(margin_s * RATE) + 1) - lo)
    n_in = source.n_frames
    for k in range(n_copies):
        n_out = round((n_in - 1) / rng.uniform(0.85, 1.25)) + 1
        warp = random_warp(n_out, n_in, rng, (0.7, 1.5))
        copy = pose_noise(time_warp_clip(source, warp), rng, noise_deg)
        copy = _turned(copy, rng.uniform(-np.pi, np.pi), np.array([rng.uniform(-3, 3), 0.0, rng.uniform(-3, 3)]))
        before, after = hosts[rng.integers(len(hosts))], hosts[rng.integers(len(hosts))]
        nb, na = int(rng.integers(20, 60)), int(rng.integers(20, 60))
        b0 = int(rng.integers(0, before.n_frames - nb))
        a0 = int(rng.integers(0, after.n_frames - na))
        pieces = [sample(before, b0, nb), copy, sample(after, a0, na)]
        key = f"kick/planted_{k:02d}"
        pc.clips[key] = _concat(pieces, key.split("/")[1])
        pc.categories[key] = "kick"
        full = np.full(nb + n_out + na, np.nan)
        full[nb:nb + n_out] = warp + lo
        pc.warps[key] = full
        inv = np.interp([query.start - lo, query.end - lo], warp, np.arange(n_out))
        pc.expected[key] = Segment(key, nb + round(inv[0]), nb + round(inv[1]))
    for c in distractors:
        key = f"{c}/{c}_00"
        pc.clips[key] = generate_clip(c, 0, seed + 2, fps=RATE)[0]
        pc.categories[key] = c
    return pc


def sample(motion: Motion, start: int, n: int) -> Motion:
    """Frames ``start..start + n − 1`` of a clip."""
    return replace(motion, root_positions=motion.root_positions[start:start + n],
                   rotations=motion.rotations[start:start + n], translations={})


def variant_chain(seed: int = 0, n_variants: int = 5, step_deg: float = 6.0, noise_deg: float = 0.3,
                  distractors: tuple[str, ...] = ("punch", "reach", "idle")) -> PlantedCorpus:
    """The query clip and variants V1..Vn of it: Vk bends the spine and raises both arms by
    k·``step_deg`` (plus a mild random warp and noise), so Vk is close to V(k±1) and far from the
    query for large k; ``expected`` lists them in chain order."""
    rng = np.random.default_rng(seed + 100)
    source, query = _query_clip(seed)
    pc = PlantedCorpus(RATE, query, {query.clip: source}, {query.clip: "kick"})
    n_in = source.n_frames
    for k in range(1, n_variants + 1):
        v = _bent(source, k * step_deg)
        n_out = round((n_in - 1) / rng.uniform(0.95, 1.05)) + 1
        warp = random_warp(n_out, n_in, rng, (0.8, 1.25))
        v = pose_noise(time_warp_clip(v, warp), rng, noise_deg)
        key = f"kick/variant_{k}"
        pc.clips[key] = replace(v, name=key.split("/")[1])
        pc.categories[key] = "kick"
        pc.warps[key] = warp
        inv = np.interp([query.start, query.end], warp, np.arange(n_out))
        pc.expected[key] = Segment(key, round(inv[0]), round(inv[1]))
    for c in distractors:
        key = f"{c}/{c}_00"
        pc.clips[key] = generate_clip(c, 0, seed + 2, fps=RATE)[0]
        pc.categories[key] = c
    return pc


def _bent(motion: Motion, deg: float) -> Motion:
    """The clip with its spine bent forward and both arms raised sideways by ``deg`` (backward and
    lowered for ``deg`` < 0) at every frame."""
    sk = motion.skeleton
    joints = [sk.index(n) for n in ("Spine1", "Spine2", "LeftArm", "RightArm")]
    ang = np.zeros((motion.n_frames, sk.n_joints, 3))
    ang[:, joints[:2], 1] = deg  # spine (about x, Euler order ZXY)
    ang[:, joints[2:], 0] = np.array([-1.0, 1.0]) * deg  # arms (about z)
    return replace(motion, rotations=quat_mul(motion.rotations, quat_from_euler(ang, "ZXY")))


def near_copy_chain(seed: int = 0, step_deg: float = 6.0, noise_deg: float = 0.3) -> PlantedCorpus:
    """:func:`variant_chain` plus two clips: ``kick/copy``, the query clip with pose noise only (a
    near copy: its match is ~30× closer than V1's), and ``kick/side``, the query clip bent the other
    way by 2·``step_deg`` (directly as close to the query as V2, far from every Vk). ``expected``
    lists the copy, then V1..V5 in chain order; the side variant is not in it."""
    pc = variant_chain(seed, step_deg=step_deg, noise_deg=noise_deg)
    rng = np.random.default_rng(seed + 200)
    source = pc.clips[pc.query.clip]
    pc.clips["kick/copy"] = replace(pose_noise(source, rng, noise_deg), name="copy")
    pc.clips["kick/side"] = replace(pose_noise(_bent(source, -2 * step_deg), rng, noise_deg), name="side")
    pc.categories.update({"kick/copy": "kick", "kick/side": "kick"})
    pc.expected = {"kick/copy": Segment("kick/copy", pc.query.start, pc.query.end), **pc.expected}
    return pc


class CorpusWebs(Mapping[str, list[tuple[str, MatchWeb]]]):
    """The search's web source over in-memory clips: clip -> [(other clip, web with the clip as
    rows)] against every clip (itself included). Webs are built on first use (features + coarse-to-
    fine webs, no store, no Prefect), each unordered pair once."""

    def __init__(self, clips: dict[str, Motion], cfg: MatchWebParams | None = None,
                 features: FeatureParams | None = None):
        self.clips, self.cfg = clips, cfg or MatchWebParams()
        fc = features or FeatureParams()
        self.weights = point_weights(next(iter(clips.values())).skeleton, fc)
        self.feats = {k: {float(r): clip_features(m, float(r), fc) for r in fc.rates} for k, m in clips.items()}
        self._pairs: dict[tuple[str, str], MatchWeb] = {}

    def web(self, a: str, b: str) -> MatchWeb:
        """The web with rows ``a`` and columns ``b``."""
        if (a, b) not in self._pairs:
            if (b, a) in self._pairs:
                return transpose(self._pairs[(b, a)])
            self._pairs[(a, b)] = build_web(self.feats[a], self.feats[b], self.weights, self.cfg, self_pair=a == b)
        return self._pairs[(a, b)]

    def all_webs(self) -> list[MatchWeb]:
        """Every web once, each unordered pair (itself included), as ``StoreWebs.all_webs``."""
        names = list(self.clips)
        return [self.web(a, b) for i, a in enumerate(names) for b in names[i:]]

    def __getitem__(self, clip: str) -> list[tuple[str, MatchWeb]]:
        if clip not in self.clips:
            raise KeyError(clip)
        return [(o, self.web(clip, o)) for o in self.clips]

    def __iter__(self) -> Iterator[str]:
        return iter(self.clips)

    def __len__(self) -> int:
        return len(self.clips)
