"""Benchmark: registration of 20 matches (KG04 §4.1, design §6). Prints figures; not a test.

    .venv/bin/python bench/register.py [--matches 20] [--repeat 3]

A clip and ``--matches`` noisy copies under known random time warps (local speed 0.7-1.5x) form
a match graph (star edges from the query plus chain edges copy i-1 -> copy i that are cheaper, so
half the nodes are reached through another copy); edge cells are the optimal paths on the
segment grids (not timed). Timed: ``register`` with the band around each edge's path (default)
and with the dense DP over every segment rectangle (``band_s=None``), in the same run, plus the
RMS error of the recovered warps against the truth (30 Hz frames). Clips: the synthetic demo walk
(4.5 s), the same walk slowed 3x (13.5 s segments: the band's advantage grows with length), and,
when present, real DeepMimic clips (``store.datasets.mocap_root()``). BLAS runs single-threaded
(unless the environment says otherwise): the dense baseline's GEMMs are small, and on a busy
machine threaded BLAS only adds contention, which would flatter the band.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from motionweb.store.datasets import ENV_VAR, mocap_root
from motionweb.store.deepmimic import read_deepmimic
from motionweb.store.demo.corpus import generate_clip
from motionweb.store.demo.perturb import pose_noise, random_warp, time_warp_clip
from motionweb.store.motion import Motion
from motionweb.tasks.distance import distance_grid
from motionweb.tasks.features import FeatureParams, clip_features, point_weights
from motionweb.tasks.matchgraph import MatchEdge, MatchGraph, MatchNode, Segment
from motionweb.tasks.matchweb.band import optimal_path
from motionweb.tasks.matchweb.params import MatchWebParams
from motionweb.tasks.register import register

from bench.timing import best_of

RATE = 30.0
CFG = MatchWebParams()
REAL = ("walk", "kick", "punch", "cartwheel", "getup_faceup")


def planted_graph(base: Motion, n_matches: int, seed: int):
    """Query = the whole clip at RATE; copies under random warps with pose noise; truth maps."""
    rng = np.random.default_rng(seed)
    fc = FeatureParams()
    feats = {"query": clip_features(base, RATE, fc)}
    w = point_weights(base.skeleton, fc)
    nodes = [MatchNode(Segment("query", 0, len(feats["query"]) - 1))]
    truth = {}
    scale = base.fps / RATE
    for c in range(1, n_matches + 1):
        mean = rng.uniform(0.8, 1.25)
        n_out = max(3, round((base.n_frames - 1) / mean) + 1)
        warp = random_warp(n_out, base.n_frames, rng)
        name = f"copy{c}"
        feats[name] = clip_features(pose_noise(time_warp_clip(base, warp), rng), RATE, fc)
        truth[name] = lambda u, w_=warp: np.interp(np.asarray(u) * scale, w_, np.arange(len(w_))) / scale
        nodes.append(MatchNode(Segment(name, 0, len(feats[name]) - 1), tier=1))

    def edge(u: int, v: int, cost: float) -> MatchEdge:
        su, sv = nodes[u].segment, nodes[v].segment
        g = distance_grid(feats[su.clip], feats[sv.clip], w)
        return MatchEdge(u, v, cost, optimal_path(g, (0, 0), (su.end, sv.end), CFG.slope_k))

    edges = [edge(0, c, 1.0 + 0.1 * c) for c in range(1, n_matches + 1)]
    edges += [edge(c - 1, c, 0.05) for c in range(3, n_matches + 1, 2)]
    return MatchGraph(RATE, nodes, edges), feats, w, truth


def bench(label: str, base: Motion, n_matches: int, repeat: int) -> None:
    graph, feats, w, truth = planted_graph(base, n_matches, seed=3)
    register(graph, feats, w, CFG)  # compile / warm up
    t_band, reg = best_of(lambda: register(graph, feats, w, CFG), repeat)
    t_dense, dense = best_of(lambda: register(graph, feats, w, CFG, band_s=None), repeat)
    rms = [float(np.sqrt(np.mean((reg.frames[:, c] - truth[s.clip](reg.u)) ** 2)))
           for c, s in enumerate(reg.segments) if c]
    band_cells = np.mean([e.alignment.n_cells for e in reg.edges])
    dense_cells = np.mean([e.alignment.n_cells for e in dense.edges])
    depth = max(len(_path(reg, c)) for c in range(len(reg.nodes)))
    relaxed = sum(not e.alignment.in_valid_region for e in reg.edges)
    print(f"{label:<28} {reg.segments[0].n_frames:>6} {len(reg.edges):>5} {depth:>5} {band_cells:>9.0f} "
          f"{dense_cells:>9.0f} {t_band * 1e3:>8.1f} {t_dense * 1e3:>8.1f} {t_dense / t_band:>6.1f}x "
          f"{np.mean(rms):>7.2f} {np.max(rms):>7.2f} {relaxed:>7}")


def _path(reg, c: int) -> list[int]:
    out = []
    while c > 0:
        out.append(c)
        c = reg.parents[c]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--matches", type=int, default=20)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    print(f"register {args.matches} matches at {RATE:g} Hz (band = ceil(0.25 s * rate) = 8 frames; "
          "dense = the same DP over every segment rectangle, GEMM values)")
    print(f"{'clip':<28} {'frames':>6} {'edges':>5} {'depth':>5} {'band cells':>9} {'dense cells':>9} "
          f"{'band ms':>8} {'dense ms':>8} {'ratio':>7} {'rms':>7} {'max rms':>7} {'relaxed':>7}")
    walk, _ = generate_clip("walk", 0, 7, 60.0)
    bench("demo walk 4.5 s", walk, args.matches, args.repeat)
    slow = time_warp_clip(walk, np.linspace(0, walk.n_frames - 1, 3 * walk.n_frames - 2))
    bench("demo walk x3, 13.5 s", slow, args.matches, args.repeat)
    motions = mocap_root() / "deepmimic" / "motions"
    if not motions.is_dir():
        print(f"real DeepMimic clips skipped: {motions} not found (set {ENV_VAR})")
        return
    for name in REAL:
        m = read_deepmimic(motions / f"humanoid3d_{name}.txt")
        bench(f"deepmimic {name} {m.duration:.1f} s", m, args.matches, args.repeat)


if __name__ == "__main__":
    main()
