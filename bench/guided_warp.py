"""Benchmark: guided time warping at the problem sizes of HDP07 Table 1, on CMU trials.

    .venv/bin/python -m bench.guided_warp [--python-dp subset|all|none] [--repeat 3]

For each row (n input, m output, r reference frames after the reduction to compression, skip s)
an input and a reference of exactly those lengths are built from CMU trials (subject 16's jumps
and walk, subject 14's boxing, subject 01's playground jumps) resampled to 30 Hz (the paper's
rate) and looped/concatenated (root travel carried over), then timed:
objective (features + all n s² local scores), full optimization (the numba DP over the reachable
windows), heuristic (§3.3: coarse 1/8 solve + banded full-rate DP) and a straightforward
pure-Python DP of the same recurrence (on a subset by default: it is slow). The paper's times
(2.4 GHz Pentium 4; objective in C++ with ANN, optimization in MATLAB) are printed beside ours.
Then HDP07 §4.1's preservation experiment on every jump of subject 16 (the manifest's labels):
each trial compressed to 50% and 60% and expanded to 150% with itself as reference; the speed of
its flight phase (kinematic: both feet off the clip's floor) and of the ground phases before and
after it, beside the linear warp's.
"""

from __future__ import annotations

import argparse
import csv
import os
import sys
from dataclasses import replace

import numpy as np
from motionweb.store.datasets import mocap_root
from motionweb.store.formats import read_motion
from motionweb.store.kinematics import airborne_intervals, resample, sample_motion
from motionweb.store.motion import Motion
from motionweb.tasks.guided_warp import (
    Reduction,
    WarpParams,
    band_windows,
    coarse_solution,
    dag_path,
    feasible_windows,
    feature_spec,
    fixed_length_path,
    guided_warp,
    linear_warp,
    local_scores,
    motion_track,
    path_cost,
    playback_speed,
    reference_features,
)

from bench.timing import best_of

# HDP07 Table 1: trial, n, m, r, s, objective s, optimization s, heuristic s (None: not reported)
TABLE1 = [
    ("V1", 493, 280, 493, 8, 1.3, 2.7, 0.17),
    ("V2", 316, 180, 316, 10, 1.7, 1.4, 0.11),
    ("V3", 378, 180, 378, 8, 1.9, 1.4, 0.14),
    ("V4", 486, 320, 486, 8, 1.0, 2.6, 0.20),
    ("V5", 401, 150, 101, 4, 0.3, 0.7, 0.06),
    ("V6", 601, 301, 301, 8, 1.3, 3.8, 0.23),
    ("V7", 573, 143, 45, 8, 0.9, 1.8, 0.14),
    ("V8", 1524, 590, 91, 8, 2.5, 0.1, None),
]
# clips per row (CMU trials): the input's source clips (concatenated, looped) and the reference's.
# V1-V3 silence removal around jumps, V4 walking then jumping, V5 an expanded jump, V6 boxing,
# V7 a walk with a short reference, V8 playground jumps (unconstrained)
CLIPS = {
    "V1": (["16_01"], ["16_01"]),
    "V2": (["16_03"], ["16_03"]),
    "V3": (["16_06"], ["16_06"]),
    "V4": (["16_16", "16_06"], ["16_16", "16_06"]),
    "V5": (["16_05"], ["16_05"]),
    "V6": (["14_02"], ["14_02"]),
    "V7": (["16_16"], ["16_16"]),
    "V8": (["01_01"], ["01_01"]),
}
RATE = 30.0
BAND = WarpParams().band
CMU = "cmu"


def clip(name: str) -> Motion:
    """A CMU trial (``"16_06"``) at 30 Hz."""
    return resample(read_motion(mocap_root() / CMU / "asf_amc" / name.split("_")[0] / f"{name}.amc"), RATE)


def concat(parts: list[Motion]) -> Motion:
    """Clips one after another, each one's root moved to continue where the previous ended."""
    roots, rots = [], []
    shift = np.zeros(3)
    for p in parts:
        r = p.root_positions.copy()
        r[:, [0, 2]] += shift[[0, 2]] - r[0, [0, 2]]
        roots.append(r)
        rots.append(p.rotations)
        shift = r[-1] + (r[-1] - r[-2])
    return replace(parts[0], root_positions=np.concatenate(roots), rotations=np.concatenate(rots))


def build(names: list[str], frames: int, upsample: int = 1) -> Motion:
    """``frames`` frames (at 30 Hz, or ``upsample`` times denser) from the named clips, looped."""
    base = concat([clip(n) for n in names])
    want = (frames - 1) // upsample + 1
    loops = [base]
    while sum(x.n_frames for x in loops) < want:
        loops.append(base)
    m = concat(loops).slice(0, want)
    if upsample > 1:
        m = sample_motion(m, np.linspace(0, want - 1, frames))
    assert m.n_frames == frames
    return replace(m, fps=RATE)


def python_dp(table: np.ndarray, m: int) -> tuple[list[int], float]:
    """The recurrence c_p(j,k) = min_i c_{p-1}(i,j) + f(i,j,k) in plain Python loops (no windows)."""
    n, s, _ = table.shape
    inf = float("inf")
    f = table.tolist()
    cost = [[inf] * s for _ in range(n)]  # cost[k][b-1]: best path ending with vertex (k-b, k)
    for k in range(1, min(s, n - 1) + 1):
        cost[k][k - 1] = 0.0
    backs = []
    for _layer in range(1, m - 1):
        new = [[inf] * s for _ in range(n)]
        back = [[0] * s for _ in range(n)]
        for k in range(n):
            for b in range(1, s + 1):
                j = k - b
                if j < 1:
                    break
                best, arg = inf, 0
                row = cost[j]
                fj = f[j]
                for a in range(1, s + 1):
                    v = row[a - 1] + fj[a - 1][b - 1]
                    if v < best:
                        best, arg = v, a
                new[k][b - 1] = best
                back[k][b - 1] = arg
        cost = new
        backs.append(back)
    last = cost[n - 1]
    b = min(range(s), key=lambda x: last[x]) + 1
    total = last[b - 1]
    path = [n - 1]
    k = n - 1
    for back in reversed(backs):
        a = back[k][b - 1]
        k -= b
        path.append(k)
        b = a
    path.append(k - b)
    return path[::-1], total


def bench_row(row, repeat: int, run_python: bool) -> dict:
    name, n, m, r, s, _p_obj, _p_opt, _p_heu = row
    ins, refs = CLIPS[name]
    up_in = max(1, round((n - 1) / (r - 1))) if r < n else 1
    motion = build(ins, n, upsample=up_in if r < n else 1)
    reference = build(refs, r) if r < n else motion
    rec: dict = {"name": name, "n": n, "m": m, "r": r, "s": s}

    def objective():
        track = motion_track(motion)
        ref_track = track if reference is motion else motion_track(reference)
        spec = feature_spec(ref_track)
        return local_scores(track, reference_features(ref_track, spec), s, spec)

    rec["objective"], table = best_of(objective, repeat)
    if name == "V8":
        rec["optimization"], (path, cost) = best_of(lambda: dag_path(table), repeat)
        rec["cost"] = cost
        rec["out_frames"] = len(path)
        return rec
    red = Reduction(1, n, m, ((0, 0), (n - 1, m - 1)), False)
    lo, hi = feasible_windows(n, m, s, red.keys)
    rec["optimization"], (path, cost) = best_of(lambda: fixed_length_path(table, m, lo, hi), repeat)
    rec["cost"] = cost

    def heuristic():
        coarse = coarse_solution(table, red, s, 8)
        blo, bhi = band_windows(coarse, m, BAND, lo, hi)
        return fixed_length_path(table, m, blo, bhi)

    rec["heuristic"], (_hpath, hcost) = best_of(heuristic, repeat)
    rec["heuristic_cost"] = hcost
    assert abs(path_cost(table, path) - cost) < 1e-6 * max(1.0, cost)
    if run_python:
        rec["python"], (_ppath, pcost) = best_of(lambda: python_dp(table, m), 1)
        assert abs(pcost - cost) < 1e-6 * max(1.0, cost), (pcost, cost)
    return rec


def subject16_jumps() -> list[str]:
    """Trial names of subject 16's jumps, from the manifest's labels."""
    with open(mocap_root() / CMU / "manifest.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    return sorted(r["path"].rsplit("/", 1)[-1][:-4] for r in rows
                  if r["category"] == "jump" and r["path"].startswith("asf_amc/16/"))


def preservation_report() -> list[str]:
    """HDP07 §4.1 on subject 16's jumps: flight and ground-phase speeds, guided vs linear."""
    lines = ["HDP07 §4.1 preservation, subject 16's jumps at 30 Hz, each its own reference "
             "(speeds: source time per output time; flight = both feet off the clip's floor)",
             f"{'trial':6s} {'frames':>6s} {'flight':>9s} {'length':>6s} | {'flight':>6s} {'before':>6s} "
             f"{'after':>6s} | {'linear':>6s}"]
    worst = 0.0
    for name in subject16_jumps():
        m = clip(name)
        f0, f1 = max(airborne_intervals(m), key=lambda r: r[1] - r[0])
        n = m.n_frames
        for frac in (0.5, 0.6, 1.5):
            n_out = round(frac * (n - 1)) + 1
            r = guided_warp(m, n_out=n_out, resample_motion=False)
            lin = linear_warp(m, n_out, resample_motion=False)
            fl = playback_speed(r.times, f0, f1)
            worst = max(worst, abs(fl - 1.0))
            lines.append(f"{name:6s} {n:6d} {f0:4d}-{f1:<4d} {frac:5.0%} | {fl:6.3f} {playback_speed(r.times, 0, f0):6.2f} "
                         f"{playback_speed(r.times, f1, n - 1):6.2f} | {playback_speed(lin.times, f0, f1):6.3f}")
    lines.append(f"largest flight-speed deviation from 1x: {100 * worst:.1f}% (target <= 10%)")
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--python-dp", choices=["subset", "all", "none"], default="subset")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    root = mocap_root()
    if not (root / CMU / "manifest.csv").is_file():
        sys.exit(f"CMU motion capture not found under {root / CMU} (set MOTIONWEB_MOCAP)")
    # compile the numba kernels outside the timings
    warm = np.random.default_rng(0).random((20, 3, 3))
    fixed_length_path(warm, 10)
    dag_path(warm)
    subset = {"V2", "V5", "V7"}
    print(f"HDP07 Table 1 sizes on CMU trials at {RATE:g} Hz; best of {args.repeat}; "
          f"{os.cpu_count()} cores; times in ms (paper's in s on a 2.4 GHz Pentium 4)")
    head = (f"{'trial':5s} {'n':>5s} {'m':>4s} {'r':>4s} {'s':>3s} | {'objective':>9s} {'paper':>6s} | "
            f"{'optim':>7s} {'paper':>6s} {'ratio':>6s} | {'heur':>6s} {'paper':>6s} {'cost+':>6s} | "
            f"{'pyDP':>8s} {'speedup':>8s}")
    print("inputs / references: " + "; ".join(f"{k} {'+'.join(a)} / {'+'.join(b)}" for k, (a, b) in CLIPS.items()))
    print(head)
    print("-" * len(head))
    rows = []
    for row in TABLE1:
        run_py = args.python_dp == "all" or (args.python_dp == "subset" and row[0] in subset)
        rec = bench_row(row, args.repeat, run_py and row[0] != "V8")
        rows.append(rec)
        p_obj, p_opt, p_heu = row[5], row[6], row[7]
        heur = f"{rec['heuristic'] * 1e3:6.2f}" if "heuristic" in rec else f"{'-':>6s}"
        pheu = f"{p_heu:6.2f}" if p_heu is not None else f"{'-':>6s}"
        extra = (f"{100 * (rec['heuristic_cost'] / rec['cost'] - 1):5.2f}%" if "heuristic_cost" in rec
                 else f"{'-':>6s}")
        py = (f"{rec['python'] * 1e3:8.0f} {rec['python'] / rec['optimization']:7.0f}x" if "python" in rec
              else f"{'-':>8s} {'-':>8s}")
        print(f"{rec['name']:5s} {rec['n']:5d} {rec['m']:4d} {rec['r']:4d} {rec['s']:3d} | "
              f"{rec['objective'] * 1e3:9.1f} {p_obj:6.2f} | {rec['optimization'] * 1e3:7.2f} {p_opt:6.2f} "
              f"{p_opt / rec['optimization']:5.0f}x | {heur} {pheu} {extra} | {py}")
    worst_opt = max(r["optimization"] / row[6] for r, row in zip(rows, TABLE1, strict=True))
    worst_heu = max(r.get("heuristic", 0.0) for r in rows)
    print(f"\nworst optimization time / paper's: 1/{1 / worst_opt:.0f} (target <= 1/20); "
          f"slowest heuristic: {worst_heu * 1e3:.2f} ms (target <= 20 ms)")
    print("ratio = paper optimization time / ours; cost+ = heuristic path cost above the optimum; "
          "pyDP = plain-Python DP of the same recurrence over all vertices, speedup = pyDP / ours")
    print("V8 is unconstrained (DAG shortest path, output length free: "
          f"{rows[-1]['out_frames']} frames)")
    print()
    print("\n".join(preservation_report()))


if __name__ == "__main__":
    main()
