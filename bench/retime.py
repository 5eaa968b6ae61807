"""MPS06 retiming benchmark on the real DeepMimic clips (humanoid.urdf masses) beside MPS06 Fig. 12.

Run: .venv/bin/python bench/retime.py
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
from scipy.optimize import linprog

from store.datasets import mocap_root
from store.deepmimic import default_urdf, read_deepmimic, read_humanoid_urdf
from tasks.dynamics import dynamics_terms
from tasks.retime import (
    N_ROOT,
    FrameLP,
    PolygonOptions,
    RetimeOptions,
    objective_function,
    prepare,
    report,
    retime_plan,
)

OPTS = RetimeOptions(knots_per_second=8.0)


def clip(name: str):
    path = mocap_root() / "deepmimic" / "motions" / f"humanoid3d_{name}.txt"
    return read_deepmimic(path), read_humanoid_urdf(default_urdf(path))


def lp_baseline(plan, frame: int, n_dir: int = 24) -> tuple[float, float]:
    """ms per direction: scipy linprog from scratch vs one highspy model with objective changes."""
    cols = plan.contacts.columns(frame)
    N = plan.contacts.basis[frame][:, cols]
    A, B, C = plan.A[frame], plan.B[frame], plan.C[frame]
    tol, lim = plan.polygons.tolerance[frame], plan.original.limits[N_ROOT:]
    G = np.hstack([A[:, None], B[:, None], -N])
    a_ub = np.vstack([G[:N_ROOT], -G[:N_ROOT], G[N_ROOT:], -G[N_ROOT:]])
    b_ub = np.concatenate([tol - C[:N_ROOT], tol + C[:N_ROOT], lim - C[N_ROOT:], lim + C[N_ROOT:]])
    po = PolygonOptions(speed_max=OPTS.speed_max)
    bounds = [(-po.pdd_max, po.pdd_max), (0, po.speed_max**2)] + [(0, None)] * len(cols)
    dirs = [np.array([np.cos(a), np.sin(a)]) for a in np.linspace(0, 2 * np.pi, n_dir, endpoint=False)]
    t = time.perf_counter()
    for d in dirs:
        linprog(-np.concatenate([d, np.zeros(len(cols))]), A_ub=a_ub, b_ub=b_ub, bounds=bounds, method="highs")
    slow = (time.perf_counter() - t) / n_dir * 1e3
    t = time.perf_counter()
    lp = FrameLP(A, B, C, N, plan.original.limits, po)
    lp.set_residual_bound(tol)
    for d in dirs:
        lp.solve(np.concatenate([d, [0.0], np.zeros(len(cols))]))
    fast = (time.perf_counter() - t) / n_dir * 1e3
    return slow, fast


def main() -> None:
    print("MPS06 Fig. 12 (16_16 walk, 2006 hardware): Force 66, Feasible 12, Obj 0.0014 ms/frame")
    print("targets: dynamics <= 1, polygons <= 5, objective <= 0.002 ms/frame; 300-frame retime <= 2 s")
    print("CMU trials (16_06, 16_03, 16_16) are not in the shared data; DeepMimic clips stand in.\n")
    print(f"{'clip':8} {'frames':>6} {'dyn ms/f':>9} {'poly ms/f':>10} {'LPs/f':>6} {'obj ms/f':>9} "
          f"{'retime s':>9} {'half s':>7} {'linprog/highspy ms/LP':>22}")
    for name in ("jump", "walk", "run"):
        motion, hum = clip(name)
        plan0 = prepare(motion, OPTS, humanoid=hum)  # warm-up (numba compile, caches)
        t = time.perf_counter()
        dynamics_terms(plan0.body, motion)
        dyn = (time.perf_counter() - t) / motion.n_frames * 1e3
        t = time.perf_counter()
        plan = prepare(motion, OPTS, humanoid=hum)
        prep = time.perf_counter() - t
        poly = plan.polygons.seconds / motion.n_frames * 1e3
        res_spline = retime_plan(plan, motion.duration / 2, None, OPTS)[1]
        fun = objective_function(plan.baked, res_spline.spline, motion.fps, motion.duration / 2,
                                 4 * motion.n_frames)
        z = res_spline.z
        fun(z)
        t = time.perf_counter()
        for _ in range(200):
            fun(z)
        obj = (time.perf_counter() - t) / 200 / motion.n_frames * 1e3
        t = time.perf_counter()
        retime_plan(plan, motion.duration / 2, None, OPTS)
        half = time.perf_counter() - t
        slow, fast = lp_baseline(plan, motion.n_frames // 3)
        print(f"{name:8} {motion.n_frames:6d} {dyn:9.3f} {poly:10.2f} {plan.polygons.n_lps / motion.n_frames:6.1f} "
              f"{obj:9.4f} {prep + half:9.2f} {half:7.2f} {slow:10.3f} / {fast:.3f} (x{slow / fast:.1f})")
    # 300-frame clip: the jump resampled to 300 frames
    motion, hum = clip("jump")
    from tasks.kinematics import resample
    long = replace(resample(motion, motion.fps * 299 / (motion.n_frames - 1)), name="jump300")
    t = time.perf_counter()
    plan = prepare(long, OPTS, humanoid=hum)
    retime_plan(plan, long.duration / 2, None, OPTS)
    print(f"\nfull retime of a {long.n_frames}-frame clip (jump resampled to {long.fps:.0f} fps, half time): "
          f"{time.perf_counter() - t:.2f} s")

    print("\nExperiments on the DeepMimic jump (objective 'match'; flights = no foot in contact):")
    motion, hum = clip("jump")
    base = prepare(motion, OPTS, humanoid=hum)
    g0 = base.body.default_gravity()
    print(f"  infeasible source frames (contact model cannot explain them): {np.flatnonzero(base.polygons.infeasible).tolist()}")
    cases = [("half time", None, None, motion.duration / 2), ("gravity x0.5", g0 * 0.5, None, motion.duration),
             ("gravity x2", g0 * 2, None, motion.duration),
             ("gravity sideways (+x, 30 deg)", np.array([9.81 * np.sin(np.pi / 6), -9.81 * np.cos(np.pi / 6), 0.0]),
              None, motion.duration),
             ("left_hip mass x10", None, {"left_hip": 10.0}, motion.duration)]
    for label, g, mass, dur in cases:
        plan = prepare(motion, OPTS, humanoid=hum, gravity=g, mass=mass)
        _, res = retime_plan(plan, dur, None, OPTS)
        rep = report(plan, res)
        fl = "; ".join(f"flight {f['source_duration']:.3f}s -> {f['output_duration']:.3f}s (x{f['ratio']:.2f})"
                       for f in rep["flights"]) or "no flight"
        print(f"  {label:30} {fl}; output frames outside polygons {len(rep['infeasible_output_frames'])}/"
              f"{rep['frames_out']}; contacts {rep['contacts']}")


if __name__ == "__main__":
    main()
