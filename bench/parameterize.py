"""Parameterized motion benchmark (KG04 §4.4), each figure beside the paper's.

Run from the repo root: ``python -m bench.parameterize`` (the machine is shared: timings are the
best of a few repeats and the load average is printed). Printed:

* sampling 1000 parameter samples (KG04 §4.4: 1.7-6.7 s) on demo reaches (wrist at the apex, 3-D)
  and demo walks (final root position, 2-D); target ≤ 0.5 s;
* synthesis of one motion from a target (KG04: "in real time"): k-NN weights, weights + f, the
  blend at 60 fps without and with foot IK, and the whole path target -> motion with plants held;
  target ≤ 5 ms for a 2 s motion (best of 10: the machine is shared);
* cost versus the number of examples (10 / 50 / 200 examples) for sampling and synthesis, and a
  blend of all examples for contrast (KG04: all 46 walks in one blend took an order of magnitude
  longer than the sparse blend);
* stored size of a space as a percentage of its examples' motion data (KG04: 3.2% mean, 8.2% worst).
"""

from __future__ import annotations

import os
import tempfile
from dataclasses import replace

import numpy as np
from motionweb.store.demo.corpus import generate_clip
from motionweb.store.zarr_store import MotionStore
from motionweb.tasks.blend import blend, blend_path, blend_poses, keytime_registration, registered_examples
from motionweb.tasks.parameterize import FinalRoot, ParameterizeParams, build_space, parse_param

from bench.timing import best_of

RATE = 30.0


def reach_space():
    clips = [generate_clip("reach", v, 7) for v in range(24)]
    side = clips[0][1]["params"]["side"]
    clips = [c for c in clips if c[1]["params"]["side"] == side]
    keys = []
    for _, t in clips:
        a = next(x for x in t["actions"] if x["label"] == "reach")
        keys.append([0.0, a["start_s"], a["apex_s"], a["end_s"]])
    end = min(t["duration"] - k[-1] for k, (_, t) in zip(keys, clips, strict=True))
    keys = [np.array([*k, k[-1] + end]) for k in keys]
    motions = [m for m, _ in clips]
    ex = registered_examples(motions, keytime_registration(motions, keys))
    hand = clips[0][1]["targets"][0]["effector"]
    return motions, ex, parse_param(f"position:{hand}@{keys[0][2]:.6f}")


def walk_space(variants=range(12)):
    clips = [generate_clip("walk", v, 7) for v in variants]
    n = min(len(t["contacts"]["left"]) for _, t in clips)
    keys = [np.array([s / t["fps"] for s, _ in t["contacts"]["left"][1:n]]) for _, t in clips]
    motions = [m for m, _ in clips]
    return motions, registered_examples(motions, keytime_registration(motions, keys)), FinalRoot()


def many_examples(ex, n: int, rng: np.random.Generator):
    """n examples: random convex mixtures of ``ex``'s registered arrays (a larger example set with
    the same timeline and realistic variety)."""
    w = rng.dirichlet(np.full(ex.n, 0.5), size=n)
    local = np.einsum("mn,nujc->mujc", w, ex.local)
    local /= np.linalg.norm(local, axis=-1, keepdims=True)
    return replace(ex, names=[f"mix{i}" for i in range(n)], local=local, height=w @ ex.height,
                   step=np.einsum("mn,nuc->muc", w, ex.step), turn=w @ ex.turn, dt=w @ ex.dt,
                   plants=np.repeat(ex.plants[:1], n, axis=0))


def stored_fraction(space, motions) -> float:
    """Stored bytes of the space (compressed Zarr) / bytes of the examples' segments (float32
    rotations and root, as a clip's data), percent."""
    with tempfile.TemporaryDirectory() as d:
        store = MotionStore(d)
        store.write_space("x", {"params": space.params, "indices": space.indices, "weights": space.weights,
                                "example_params": space.example_params}, {})
        size = store.size_bytes()
    ex = space.examples
    data = sum(m.n_frames * (m.skeleton.n_joints * 4 + 3) * 4 for m in motions)
    return 100.0 * size / data, size, data, ex.n


def main() -> None:
    rng = np.random.default_rng(0)
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    for label, (motions, ex, fn) in (("reach (wrist at apex, 3-D)", reach_space()),
                                     ("walk (final root, 2-D)", walk_space())):
        cfg = ParameterizeParams(samples=1000)
        t, space = best_of(lambda: build_space(fn, ex, cfg), 3)
        print(f"\n{label}: {ex.n} examples, {ex.n_samples} samples of u")
        print(f"  1000 samples: {t:.3f} s -> {len(space.params)} kept   [KG04 §4.4: 1.7-6.7 s; target <= 0.5 s]")
        lo, hi = space.params.min(0), space.params.max(0)
        targets = lo + (hi - lo) * rng.random((50, space.dim))
        tw, _ = best_of(lambda: [space.weights_for(p) for p in targets], 3)
        tf, _ = best_of(lambda: [space.synthesize(p) for p in targets], 3)
        w = space.synthesize(targets[0]).weights
        tb, r = best_of(lambda: blend(ex, w, fps=60.0, measure=False), 10)
        tn, _ = best_of(lambda: blend(ex, w, fps=60.0, hold_feet=False, measure=False), 10)
        tt, _ = best_of(lambda: blend(ex, space.synthesize(targets[1]).weights, fps=60.0, measure=False), 10)
        print(f"  synthesis: k-NN weights {1e3 * tw / 50:.3f} ms, + f and {cfg.refine} refinements "
              f"{1e3 * tf / 50:.2f} ms; blend of {r.motion.duration:.1f} s at 60 fps {1e3 * tn:.2f} ms, "
              f"with foot IK {1e3 * tb:.2f} ms")
        print(f"  one motion from a target (weights, f, refinements, blend, plants held): {1e3 * tt:.2f} ms "
              f"for {r.motion.duration:.1f} s   [KG04: real time; target <= 5 ms for 2 s]")
        pct, size, data, n = stored_fraction(space, motions)
        print(f"  stored space {size / 1024:.1f} KiB = {pct:.1f}% of the {n} examples' data "
              f"({data / 1024:.0f} KiB)   [KG04: 3.2% mean, 8.2% worst]")
    motions, base, fn = walk_space(range(6))
    print("\ncost versus examples (walk mixtures, final root; 300 samples, synthesis of 50 targets)")
    for n in (10, 50, 200):
        ex = many_examples(base, n, rng)
        cfg = ParameterizeParams(samples=300)
        ts, space = best_of(lambda: build_space(fn, ex, cfg), 2)
        lo, hi = space.params.min(0), space.params.max(0)
        targets = lo + (hi - lo) * rng.random((50, space.dim))
        tw, _ = best_of(lambda: [space.weights_for(p) for p in targets], 3)
        w = space.synthesize(targets[0]).weights
        sparse, _ = best_of(lambda: (blend_path(ex, w[None]), blend_poses(ex, w[None])), 5)
        dense_w = np.full(n, 1.0 / n)
        dense, _ = best_of(lambda: (blend_path(ex, dense_w[None]), blend_poses(ex, dense_w[None])), 5)
        print(f"  {n:3d} examples: sampling {ts:.3f} s, k-NN weights {1e3 * tw / 50:.3f} ms, "
              f"blend of {np.count_nonzero(w)} examples {1e3 * sparse:.2f} ms vs all {n} {1e3 * dense:.2f} ms")


if __name__ == "__main__":
    main()
