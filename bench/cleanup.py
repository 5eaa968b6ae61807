"""Foot-slide cleanup (tasks/cleanup.py, issue 26) on every shared CMU walk.

Per walk of ``cmu/manifest.csv`` (category ``walk``: 26 ASF/AMC trials of subject 16 and the
cgspeed BVH 131_02): frames, the share of foot-frames planted, the foot skate (mean horizontal
ankle speed on the planted frames, cm/s) before and after the cleanup, the worst IK miss, the
largest change of any joint outside the legs (must be 0 to 1e-9) and the milliseconds the
cleanup took (FK of the leg paths, plant detection, compiled IK; reading the file not counted).
The target is ≤ 1 cm/s after.

Run from the repo root: ``.venv/bin/python -m bench.cleanup`` (needs the mocap folder, see
``store.datasets.mocap_root``).
"""

from __future__ import annotations

import csv
import sys
import time

import numpy as np
from motionweb.store.datasets import mocap_root
from motionweb.store.formats import read_motion
from motionweb.store.kinematics import forward_kinematics
from motionweb.tasks.cleanup import cleanup

#: cgspeed's CMU BVH declares no unit: it keeps the ASF's (inches / 0.45)
CGSPEED_SCALE = 0.0254 / 0.45
TARGET_CM_S = 1.0


def upper_body(parents: np.ndarray, hips: list[int]) -> list[int]:
    below = set(hips)
    for j, p in enumerate(parents.tolist()):
        if p in below:
            below.add(j)
    return [j for j in range(len(parents)) if j not in below]


def main() -> int:
    root = mocap_root() / "cmu"
    if not (root / "manifest.csv").is_file():
        print(f"no CMU data at {root} (set MOTIONWEB_MOCAP)")
        return 1
    with open(root / "manifest.csv") as fh:
        rows = [r for r in csv.DictReader(fh) if r["category"] == "walk"]
    cleanup(read_motion(root / rows[0]["path"]))  # compile the kernels once, outside the timings
    print(f"{'trial':28s} {'frames':>6s} {'planted':>7s} {'before':>8s} {'after':>8s} {'miss cm':>7s} "
          f"{'upper Δ m':>9s} {'ms':>6s}")
    befores, afters, worst = [], [], 0.0
    for r in rows:
        m = read_motion(root / r["path"], scale_to_m=CGSPEED_SCALE)
        t = time.perf_counter()
        res = cleanup(m)
        ms = 1000 * (time.perf_counter() - t)
        up = upper_body(m.skeleton.parents, [res.legs[s][0] for s in res.legs])
        delta = float(np.abs(forward_kinematics(res.motion)[0][:, up] - forward_kinematics(m)[0][:, up]).max()) * m.metres()
        worst = max(worst, delta)
        befores.append(res.skate_before)
        afters.append(res.skate_after)
        print(f"{r['path']:28s} {m.n_frames:6d} {res.plants.mean():7.2f} {res.skate_before:8.2f} {res.skate_after:8.3f} "
              f"{100 * res.miss_m:7.2f} {delta:9.1e} {ms:6.1f}")
    print(f"\n{len(rows)} walks: foot skate on planted frames {np.mean(befores):.2f} cm/s before (max "
          f"{np.max(befores):.2f}), {np.mean(afters):.3f} cm/s after (max {np.max(afters):.3f}; target ≤ "
          f"{TARGET_CM_S:g}); upper body moved at most {worst:.1e} m")
    return 0 if max(afters) <= TARGET_CM_S and worst <= 1e-9 else 1


if __name__ == "__main__":
    sys.exit(main())
