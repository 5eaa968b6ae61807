"""MPS06 retiming benchmark on the paper's own CMU trials of subject 16, beside MPS06 Fig. 12 and §4.

Per clip (16_16 walk, the paper's Fig. 12 clip, and the 16_06 jump, 16_35 run): ms per frame of the
dynamics coefficients (Fig. 12 "Force"), of the feasible polygons ("Feasible") and of one objective
evaluation ("Obj"), each as CPU time of this process and wall time (the machine may be shared:
the load average is printed), with baselines measured in the same run — the same polygons with
HiGHS solving every LP (``polygons.lp_solver: highs``, the previous implementation), the same polygon sweep
with scipy ``linprog`` building every LP from scratch, and the same objective kernel run by the
Python interpreter. Then a full retime of a 300-frame clip (and with HiGHS's LPs), and the paper's experiments (MPS06
§4.1-4.2, Figs. 1, 8-11) with what the flight and contact phases did. ``--all-trials``: the share
of source frames inside their polygon at the original timing for every walk, run and jump of
subject 16 (manifest.csv), with the frames that are not and why. ``--retime-all``: each of them
retimed to 0.5, 0.6, 0.7 and 1.5 of its length: the timing used, whether it met the target, the
share of output frames inside their polygon, every flight's ratio and the CPU seconds.

Run: .venv/bin/python -m bench.retime [--all-trials] [--retime-all]
"""

from __future__ import annotations

import csv
import os
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import replace
from typing import Any

import numpy as np
from motionweb.store.datasets import mocap_root
from motionweb.store.formats import read_motion
from motionweb.store.motion import Motion
from motionweb.tasks.retime import (
    PolygonParams,
    RetimeParams,
    RetimePlan,
    SplineParams,
    phase_times,
    prepare,
    report,
    retime_plan,
)
from motionweb.tasks.retime.dynamics import dynamics_terms
from motionweb.tasks.retime.objective import objective_kernel
from motionweb.tasks.retime.polygons import N_ROOT
from motionweb.tasks.retime.report import free_fall, inner_flights, original_feasibility, shortest_duration
from motionweb.tasks.retime.spline import objective_function
from scipy.optimize import linprog

OPTS = RetimeParams()
HIGHS = RetimeParams(polygons=PolygonParams(lp_solver="highs"))  # baseline: every polygon LP by HiGHS
SPLINE = RetimeParams(spline=SplineParams(timing="spline"))  # MPS06's optimized spline alone
PAPER = {"dyn": 66.0, "poly": 12.0, "obj": 0.0014}  # MPS06 Fig. 12, 16_16 walk, ms/frame
TARGET = {"dyn": 1.0, "poly": 5.0, "obj": 0.002}
CMU16 = mocap_root() / "cmu" / "asf_amc" / "16"


def clip(name: str) -> Motion:
    return read_motion(CMU16 / f"{name}.amc")


def timed(fn: Callable[[], Any], repeat: int = 1) -> tuple[Any, float, float]:
    """(result, wall s, CPU s) per call, the best of ``repeat`` calls."""
    best_w, best_c, out = np.inf, np.inf, None
    for _ in range(repeat):
        w, c = time.perf_counter(), time.process_time()
        out = fn()
        best_w, best_c = min(best_w, time.perf_counter() - w), min(best_c, time.process_time() - c)
    return out, best_w, best_c


def linprog_ms_per_lp(plan: RetimePlan, frames: list[int], n_dir: int = OPTS.polygons.directions) -> float:
    """Baseline: ms (CPU) per direction LP with scipy ``linprog`` building each LP from scratch."""
    po = plan.polygons
    total, n = 0.0, 0
    for i in frames:
        cols = plan.contacts.columns(i)
        N = plan.contacts.basis[i][:, cols]
        G = np.hstack([plan.A[i][:, None], plan.B[i][:, None], -N])
        tol, lim, C = po.tolerance[i], plan.original.limits[N_ROOT:], plan.C[i]
        a_ub = np.vstack([G[:N_ROOT], -G[:N_ROOT], G[N_ROOT:], -G[N_ROOT:]])
        b_ub = np.concatenate([tol - C[:N_ROOT], tol + C[:N_ROOT], lim - C[N_ROOT:], lim + C[N_ROOT:]])
        bounds = [(-OPTS.polygons.pdd_max, OPTS.polygons.pdd_max), (0, OPTS.polygons.speed_max**2)] + [(0, None)] * len(cols)
        for a in np.linspace(0, 2 * np.pi, n_dir, endpoint=False):
            cost = np.concatenate([[-np.cos(a), -np.sin(a)], np.zeros(len(cols))])
            c = time.process_time()
            linprog(cost, A_ub=a_ub, b_ub=b_ub, bounds=bounds, method="highs")
            total += time.process_time() - c
            n += 1
    return total / n * 1e3


def interpreted_objective(plan: RetimePlan, res: Any, fps: float, duration: float, n_s: int) -> Callable[[], float]:
    """Baseline: the same one-pass objective kernel run by the Python interpreter (numba's ``py_func``;
    the per-sample density it calls stays compiled), i.e. a Python loop over the samples."""
    fun = objective_function(plan.baked, res.spline, fps, duration, n_s)
    ob = plan.baked
    edges = np.linspace(0.0, duration, n_s + 1)
    ctrl, w = res.spline.design(0.5 * (edges[1:] + edges[:-1]))
    c = res.spline.controls(res.z)
    args = (ob.verts, ob.count, ob.inv_len2, ob.solid, ob.center, ob.theta0, ob.theta, ob.coef, ob.alpha, ctrl, w, c,
            float(fps), duration / n_s)
    assert abs(objective_kernel.py_func(*args)[0] - fun(res.z)[0]) <= 1e-9 * (1 + abs(fun(res.z)[0]))

    def run() -> float:
        return float(objective_kernel.py_func(*args)[0])

    return run


def stage_table() -> None:
    print(f"{'clip':6} {'frames':>6} | {'dynamics ms/f':>15} | {'polygons ms/f':>15} {'LPs/f':>5} "
          f"{'HiGHS':>6} {'x':>5} {'linprog':>8} {'x':>5} | {'objective ms/f':>16} {'python':>7} {'x':>5} | {'half s':>6}")
    print(f"{'':6} {'':6} | {'cpu':>7} {'wall':>7} | {'cpu':>7} {'wall':>7} {'':5} {'ms/f':>6} {'':5} {'ms/f':>8} "
          f"{'':5} | {'cpu':>8} {'wall':>7} {'ms/f':>7} {'':5} | {'cpu':>6}")
    for name in ("16_16", "16_06", "16_35"):
        motion = clip(name)
        f = motion.n_frames
        plan = prepare(motion, OPTS)  # warm-up: numba compilation, imports
        retime_plan(plan, motion.duration / 2, None, OPTS)
        _, dyn_w, dyn_c = timed(lambda m=motion, b=plan.body: dynamics_terms(b, m, OPTS.smoothing_s), repeat=2)
        plan, _, _ = timed(lambda m=motion: prepare(m, OPTS))
        poly_w = plan.polygons.seconds
        poly_c = plan.polygons.cpu_seconds
        lps = plan.polygons.n_lps / f
        base_poly = linprog_ms_per_lp(plan, list(range(0, f, max(f // 6, 1)))) * lps
        highs_poly = prepare(motion, HIGHS).polygons.cpu_seconds / f * 1e3
        _, _, half_c = timed(lambda p=plan, m=motion: retime_plan(p, m.duration / 2, None, OPTS))
        _, res = retime_plan(plan, motion.duration / 2, None, SPLINE)  # the objective is the spline's
        n_s = 4 * f
        fun = objective_function(plan.baked, res.spline, motion.fps, motion.duration / 2, n_s)
        fun(res.z)
        _, obj_w, obj_c = timed(lambda fn=fun, z=res.z: [fn(z) for _ in range(200)], repeat=5)
        ref = interpreted_objective(plan, res, motion.fps, motion.duration / 2, n_s)
        _, _, ref_c = timed(lambda fn=ref: [fn() for _ in range(2)], repeat=2)
        obj_c, obj_w, ref_c = obj_c / 200, obj_w / 200, ref_c / 2
        print(f"{name:6} {f:6d} | {dyn_c / f * 1e3:7.3f} {dyn_w / f * 1e3:7.3f} | {poly_c / f * 1e3:7.2f} "
              f"{poly_w / f * 1e3:7.2f} {lps:5.1f} {highs_poly:6.2f} {highs_poly / (poly_c / f * 1e3):5.1f} "
              f"{base_poly:8.2f} {base_poly / (poly_c / f * 1e3):5.1f} | "
              f"{obj_c / f * 1e3:8.5f} {obj_w / f * 1e3:7.5f} {ref_c / f * 1e3:7.4f} {ref_c / obj_c:5.1f} | "
              f"{half_c:6.2f}")
    pad = f"{'':7} {'':5} {'':6} {'':5} {'':8} {'':5}"
    print(f"{'MPS06':6} {'':6} | {PAPER['dyn']:7.1f} {'':7} | {PAPER['poly']:7.1f} {pad} | {PAPER['obj']:8.4f}")
    print(f"{'target':6} {'':6} | {TARGET['dyn']:7.1f} {'':7} | {TARGET['poly']:7.1f} {pad} | {TARGET['obj']:8.4f}")


def full_retime() -> None:
    walk = clip("16_16")
    part = replace(walk, root_positions=walk.root_positions[:300], rotations=walk.rotations[:300], name="16_16[:300]")
    print(f"\nfull retime of a {part.n_frames}-frame clip (16_16's first 300 frames at 120 fps, 0.8 of its length; "
          "target <= 2 s):")
    for opts in (OPTS, HIGHS):  # warm-up: compiled kernels, imports
        prepare(replace(part, root_positions=part.root_positions[:60], rotations=part.rotations[:60]), opts)
    for label, opts in (("simplex LPs", OPTS), ("HiGHS LPs (baseline)", HIGHS)):
        plan, prep_w, prep_c = timed(lambda o=opts: prepare(part, o))
        (_, res), opt_w, opt_c = timed(lambda p=plan, o=opts: retime_plan(p, 0.8 * part.duration, None, o))
        stages = ", ".join(f"{k} {v:.2f}" for k, v in plan.timings.items())
        print(f"  {label:20} CPU {prep_c + opt_c:.2f} s, wall {prep_w + opt_w:.2f} s, {res.kind} timing (prepare CPU {prep_c:.2f} s "
              f"[wall: {stages}; polygons CPU {plan.polygons.cpu_seconds:.2f}]; optimize CPU {opt_c:.2f} s, "
              f"{res.iterations} L-BFGS-B iterations, {res.n_samples} samples)")


def describe(plan: RetimePlan, res: Any) -> str:
    rep = report(plan, res)
    fl = "; ".join(f"flight {f['source_duration']:.3f} s -> {f['output_duration']:.3f} s (x{f['ratio']:.2f})"
                   for f in rep["flights"]) or "no flight"
    phases = ", ".join(f"{k} {s:.2f}->{o:.2f}" for k, (s, o) in phase_times(plan.contacts, res, plan.motion.fps).items())
    return (f"[{rep['timing']} timing] {fl}; phases (s, source->output): {phases}; output frames inside their polygon "
            f"{1 - len(rep['infeasible_output_frames']) / rep['frames_out']:.0%}; {rep['reachable']['message']}")


def sideways(motion: Motion, g: float, degrees: float) -> np.ndarray:
    """Gravity tilted ``degrees`` from straight down toward the walker's left (Y up)."""
    d = motion.root_positions[-1] - motion.root_positions[0]
    fwd = np.array([d[0], 0.0, d[2]]) / np.hypot(d[0], d[2])
    left = np.cross(np.array([0.0, 1.0, 0.0]), fwd)
    a = np.radians(degrees)
    return g * (-np.cos(a) * np.array([0.0, 1.0, 0.0]) + np.sin(a) * left)


def experiments() -> None:
    print("\nExperiments (MPS06 §4 on subject 16, objective 'match'; flight = no foot in contact; phases by feet "
          "in contact):")
    jump = clip("16_06")
    base = prepare(jump, OPTS)
    g0 = base.body.default_gravity()
    spans = {k: ", ".join(f"{a:.2f}-{b:.2f}" for a, b in v) for k, v in base.contacts.intervals(jump.fps).items()}
    print(f"  16_06 forward jump: {jump.duration:.3f} s, contacts (s) {spans}; no timing inside every polygon is "
          f"shorter than {shortest_duration(base.polygons, jump.fps):.3f} s (TOPP-RA; half the clip: "
          f"{jump.duration / 2:.3f} s)")
    names = base.body.skeleton.names
    doubled = {n: 2 * float(base.original.limits[base.body.joint_dofs(j).start]) for j, n in enumerate(names) if j}
    loose = [("friction 0.8", {"contacts": {"friction": 0.8}}), ("torque limits x2", {"torque_limits": doubled}),
             ("root_tolerance 0.05", {"polygons": {"root_tolerance": 0.05}}), ("smoothing_s 0.16", {"smoothing_s": 0.16})]
    print("    the same bound with the model loosened: " + ", ".join(
        f"{label} {shortest_duration(prepare(jump, RetimeParams.model_validate(upd)).polygons, jump.fps):.3f} s"
        for label, upd in loose))
    for label, frac in (("Fig. 1: 16_06 in half the time", 0.5), ("16_06 in 0.6 of the time", 0.6)):
        _, res = retime_plan(base, frac * jump.duration, None, OPTS)
        print(f"  {label:38} {describe(base, res)}")
        if res.kind != "spline":
            _, res = retime_plan(base, frac * jump.duration, None, SPLINE)
            print(f"  {'  (the spline alone)':38} {describe(base, res)}")
    (f0, f1), = inner_flights(base.contacts.active, jump.fps)
    mid = 0.5 * (f0 + f1)
    _, res = retime_plan(base, jump.duration, [(mid, mid - 0.3)], OPTS)
    print(f"  {'Fig. 8: 16_06, mid-flight 0.3 s earlier':38} {describe(base, res)}; speed in flight "
          f"{_speed_in(res, f0, f1)}, peak speed elsewhere x{res.pd.max():.2f}")
    high = clip("16_03")
    for k in (0.5, 2.0):
        plan = prepare(high, OPTS, gravity=g0 * k)
        _, res = retime_plan(plan, high.duration, None, OPTS, free_length=True)
        print(f"  {f'Fig. 9: 16_03 gravity x{k:g}, length free':38} {describe(plan, res)}; length "
              f"{high.duration:.3f} -> {res.t[-1]:.3f} s [ballistic flight: x{1 / np.sqrt(k):.3f}]")
    walk = clip("16_16")
    for label, kw in (("16_16 walk, normal physics", {}),
                      ("Fig. 10: 16_16, gravity 30 deg to the left", {"gravity": sideways(walk, 9.81, 30.0)}),
                      ("Fig. 11: 16_16, left femur weight x10", {"weight_factors": {"lfemur": 10.0}}),
                      ("  (its mass x10: inertia too)", {"mass": {"lfemur": 10.0}})):
        plan = prepare(walk, OPTS, **kw)
        _, res = retime_plan(plan, walk.duration, None, OPTS)
        print(f"  {label:38} {describe(plan, res)}")


def _speed_in(res: Any, t0: float, t1: float) -> str:
    tt = np.linspace(0, res.t[-1], 4000)
    p, pd, _ = res.spline.evaluate(res.z, tt)
    sel = (p > t0) & (p < t1)
    return f"x{pd[sel].min():.2f}-{pd[sel].max():.2f}" if sel.any() else "-"


def subject16_trials() -> Iterator[tuple[str, Motion, RetimePlan]]:
    """(category, clip, plan under the default physics) of every walk, run and jump of subject 16."""
    for row in csv.DictReader(open(mocap_root() / "cmu" / "manifest.csv")):
        if row["path"].startswith("asf_amc/16/") and row["category"] in ("walk", "run", "jump"):
            motion = read_motion(mocap_root() / "cmu" / row["path"])
            yield row["category"], motion, prepare(motion, OPTS)


def all_trials() -> None:
    print("\nOriginal timing inside its polygon, every walk / run / jump of subject 16 (manifest.csv):")
    shares, falls = [], []
    for category, motion, plan in subject16_trials():
        of = original_feasibility(plan)
        shares.append(of["inside_fraction"])
        fall = free_fall(plan)
        if fall["gravity"] is not None:
            falls.append(fall["gravity"])
        why = "; ".join(f"{o['frame']}: {o['why']}" for o in of["outside"][:3])
        print(f"  {motion.name} {category:5} {motion.n_frames:4d} frames: inside {of['inside_fraction']:6.1%}, "
              f"falls at {'-' if fall['gravity'] is None else format(fall['gravity'], '5.2f')} m/s², "
              f"unexplained by contacts {of['unexplained_fraction']:5.1%} (stance frames "
              f"{of['unexplained_stance_fraction']:5.1%}, flight frames {of['unexplained_flight_fraction']:5.1%})"
              f"{'  outside: ' + why if why else ''}"
              f"{' ...' if len(of['outside']) > 3 else ''}")
    print(f"  {sum(s >= 0.95 for s in shares)} of {len(shares)} trials have >= 95% inside; lowest {min(shares):.1%}")
    print(f"  free fall of the centre of mass in the flights (report.free_fall), {len(falls)} trials: median "
          f"{np.median(falls):.2f} m/s², {min(falls):.2f}-{max(falls):.2f} (gravity 9.81)")


def retimed_trials(fracs: tuple[float, ...] = (0.5, 0.6, 0.7, 1.5)) -> None:
    print(f"\nEvery walk / run / jump of subject 16 retimed to {', '.join(f'{f:g}' for f in fracs)} of its length "
          "(default config; timing p = path, s = spline; M = met, <= 10% of output frames outside; flight ratios):")
    tally: dict[tuple[str, float], list[tuple[bool, bool, float]]] = {}
    for category, motion, plan in subject16_trials():
        line = f"  {motion.name} {category:5} {motion.n_frames:4d} frames, shortest inside " \
               f"{shortest_duration(plan.polygons, motion.fps) / motion.duration:5.2f}x:"
        for f in fracs:
            (_, res), _, cpu = timed(lambda p=plan, d=f * motion.duration: retime_plan(p, d, None, OPTS))
            rep = report(plan, res)
            inside = 1 - len(rep["infeasible_output_frames"]) / rep["frames_out"]
            met = rep["reachable"]["met"]
            tally.setdefault((category, f), []).append((met, rep["timing"] == "path", inside))
            flights = ",".join(f"{x['ratio']:.2f}" for x in rep["flights"])
            line += f" | {f:g}: {rep['timing'][0]} {'M' if met else '-'} {inside:4.0%} [{flights}] {cpu:4.1f} s"
        print(line, flush=True)
    for (category, f), rows in sorted(tally.items()):
        print(f"  {category:5} x{f:g}: met {sum(r[0] for r in rows)} of {len(rows)}, path timing {sum(r[1] for r in rows)}, "
              f"mean inside {np.mean([r[2] for r in rows]):.1%}")


def main() -> None:
    print("MPS06 Fig. 12 (16_16 walk, 2006 hardware): Force 66, Feasible 12, Obj 0.0014 ms/frame")
    print("targets: dynamics <= 1, polygons <= 5, objective <= 0.002 ms/frame; 300-frame retime <= 2 s")
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs: CPU time is the comparable figure; "
          "x = baseline / ours, both measured now\n")
    stage_table()
    full_retime()
    experiments()
    if "--all-trials" in sys.argv[1:]:
        all_trials()
    if "--retime-all" in sys.argv[1:]:
        retimed_trials()


if __name__ == "__main__":
    main()
