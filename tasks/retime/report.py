"""What a retiming did: flights, contact phases, feasibility, shortest duration (design §8, MPS06 §4).

:func:`report` is the JSON-able record of one retiming (per output frame timing, torques, contact
forces, distance to the polygon) with its summary; the other functions are its parts.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from motionweb.tasks.retime.contacts import (
    BALLISTIC_TOLERANCE,
    EDGES_PER_CORNER,
    Contacts,
    fall_rate,
    pyramid,
    rest_positions,
)
from motionweb.tasks.retime.dynamics import centre_of_mass
from motionweb.tasks.retime.glitches import GLITCH_DEG_PER_S, step_degrees
from motionweb.tasks.retime.objective import contact_lambda
from motionweb.tasks.retime.pipeline import RetimeParams, RetimePlan
from motionweb.tasks.retime.polygons import MET_OUTSIDE_FRACTION, N_ROOT, FeasiblePolygons, timing_distances
from motionweb.tasks.retime.reachable import fastest_timing
from motionweb.tasks.retime.spline import RetimeResult


def shortest_duration(polys: FeasiblePolygons, fps: float) -> float:
    """The shortest duration of any timing that stays inside every polygon (MPS06 §3.3), exact for
    the polygons (:func:`.reachable.fastest_timing`); ``inf`` when no timing stays inside them all
    (an empty polygon, or a frame no timing can leave inside). A requested duration below it must
    leave the polygons somewhere. O(F · K).
    """
    fastest = fastest_timing(polys, fps)
    return fastest.duration if fastest.inside else float("inf")


#: flights shorter than this are not fitted for their free fall (too few frames for a parabola)
FREE_FALL_MIN_S = 0.15
#: standing heights (m, rest pose, joint to joint) a length unit may give a human body
HUMAN_HEIGHT_M = (0.9, 2.3)


def free_fall(plan: RetimePlan) -> dict[str, Any]:
    """The acceleration the centre of mass falls at in the clip's own flights, and with it a check
    of the length unit: a ballistic phase has gravity alone (MPS06 §4.1), so a clip whose unit is
    off by a factor k falls at 9.81 / k m/s² in every flight, and every flight the physics sees is
    wrong by as much.

    Per inner flight of at least :data:`FREE_FALL_MIN_S` (no foot down; its first and last frames
    touch), a least-squares parabola of the centre of mass's height. Returns ``gravity`` (the
    median, m/s², None without such a flight), ``flights`` (how many were fitted), ``per_flight``
    ({source start s: m/s²}), ``expected`` (what a ballistic flight of this clip falls at: the
    default gravity, or the median where the unit is suspect) and a ``note`` naming the
    ``scale_to_m`` that would make the flights fall at the default gravity. The note needs two
    flights or more that agree within :data:`.contacts.BALLISTIC_TOLERANCE` of their median and all fall
    farther than that from the default gravity, and a body that the new scale makes
    :data:`HUMAN_HEIGHT_M` tall: hands on the floor (a cartwheel, a crawl) or a bar hold one flight
    up, not all of them alike, and a unit that makes a giant is no fix. O(F · B).
    """
    m, body = plan.motion, plan.body
    g0 = float(np.linalg.norm(body.default_gravity()))
    fits, per_flight = [], {}
    for s0, s1 in inner_flights(plan.contacts.active, m.fps):
        frames = np.arange(round(s0 * m.fps) + 1, round(s1 * m.fps))
        if s1 - s0 < FREE_FALL_MIN_S or len(frames) < 4:
            continue
        fits.append(fall_rate(centre_of_mass(body, plan.terms.q[frames])[:, body.up_axis], m.fps))
        per_flight[s0] = fits[-1]
    if not fits:
        return {"gravity": None, "flights": 0, "per_flight": {}, "expected": g0, "note": ""}
    g_fall = float(np.median(fits))
    note = ""
    if g_fall > 0 and len(fits) >= 2 and all(abs(g / g_fall - 1.0) <= BALLISTIC_TOLERANCE for g in fits) \
            and abs(g_fall / g0 - 1.0) > BALLISTIC_TOLERANCE:
        scale = body.scale * g0 / g_fall
        tall = float(np.ptp(rest_positions(body.skeleton, scale)[:, body.up_axis]))
        if HUMAN_HEIGHT_M[0] <= tall <= HUMAN_HEIGHT_M[1]:
            note = (f"the centre of mass falls at {g_fall:.2f} m/s² in all {len(fits)} of the clip's flights, not "
                    f"{g0:.2f}: is the length unit right? scale_to_m {scale:.4g} (now {body.scale:.4g}) would make "
                    f"them fall at {g0:.2f} (and the body {tall:.2f} m tall)")
    return {"gravity": g_fall, "flights": len(fits), "per_flight": per_flight,
            "expected": g_fall if note else g0, "note": note}


def held_up(fall: dict[str, Any], s0: float) -> bool:
    """Whether the flight starting at ``s0`` falls more than :data:`.contacts.BALLISTIC_TOLERANCE` off what a
    ballistic flight of the clip falls at (:func:`free_fall`'s ``expected``): no foot down, yet
    something else holds or pushes the body (hands, a bar), or the contacts are off."""
    mine = fall["per_flight"].get(s0)
    return mine is not None and abs(mine / fall["expected"] - 1.0) > BALLISTIC_TOLERANCE


def phase_times(contacts: Contacts, res: RetimeResult, fps: float, n: int = 4000) -> dict[str, tuple[float, float]]:
    """Seconds spent in each contact phase ('flight', '<foot> only', 'double'): (source, output).

    The phase of a source frame is its set of feet in contact; output seconds integrate the
    phase of p(t) over ``n`` output samples — the retiming's shift between stances (MPS06 Fig.
    10-11: a leg favoured under sideways gravity or a heavy femur). O(n + F).
    """
    names = [f.name for f in contacts.feet]

    def label(row: np.ndarray) -> str:
        k = int(row.sum())
        return "flight" if k == 0 else "double" if k > 1 else f"{names[int(np.argmax(row))]} only"

    labels = [label(row) for row in contacts.active]
    f = len(labels)
    tt = (np.arange(n) + 0.5) * res.t[-1] / n
    p, _, _ = res.spline.evaluate(res.z, tt)
    frames = np.clip(np.rint(p * fps).astype(int), 0, f - 1)
    out: dict[str, tuple[float, float]] = {}
    for name in dict.fromkeys(labels):
        src = sum(lab == name for lab in labels) / fps
        dur = float(np.isin(frames, [i for i, lab in enumerate(labels) if lab == name]).sum() * res.t[-1] / n)
        out[name] = (src, dur)
    return out


def flight_intervals(active: np.ndarray, fps: float) -> list[tuple[float, float]]:
    """Source-time intervals (s) with no foot in contact, between the last and first contact frames."""
    none = ~active.any(axis=1)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], none.astype(np.int8), [0]])))
    return [((s - 1) / fps if s > 0 else 0.0, e / fps if e < len(none) else (len(none) - 1) / fps)
            for s, e in zip(edges[::2], edges[1::2], strict=True)]


def inner_flights(active: np.ndarray, fps: float) -> list[tuple[float, float]]:
    """:func:`flight_intervals` with a contact on both sides (not at the clip's first or last frame)."""
    end = (len(active) - 1) / fps
    return [(a, b) for a, b in flight_intervals(active, fps) if a > 0 and b < end]


def output_time(res: RetimeResult, src_time: float) -> float:
    """The output time at which p(t) = ``src_time`` (bisection on the monotone spline)."""
    lo, hi = 0.0, float(res.spline.out[-1])
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if res.spline.evaluate(res.z, np.array([mid]))[0][0] < src_time:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def largest_step(rotations: np.ndarray, frame: int, half: int) -> tuple[float, int]:
    """The largest one-frame turn (degrees) of a joint's rotations (F, 4, wxyz) over frames
    ``frame`` ± ``half``, and the frame it ends at: a capture glitch shows as a joint that turns
    tens of degrees in one frame (a marker swap or dropout), which no torque limit admits. O(half)."""
    lo, hi = max(frame - half, 0), min(frame + half, len(rotations) - 1)
    if hi <= lo:
        return 0.0, frame
    ang = step_degrees(rotations[lo:hi + 1])
    k = int(np.argmax(ang))
    return float(ang[k]), lo + k + 1


def original_feasibility(plan: RetimePlan, unexplained_tol: float = 0.05) -> dict[str, Any]:
    """How well the model explains the clip at its own timing (p̈, ṗ²) = (0, 1) (MPS06 §3.3).

    ``inside_fraction``: source frames whose original timing lies in their polygon; ``outside``:
    the others, each with why (a joint over its torque limit — with the joint's one-frame jump when
    the data turns it faster than ``GLITCH_DEG_PER_S`` nearby — or the root force beyond its
    tolerance). ``unexplained``: frames whose root force the contacts cannot supply within
    ``unexplained_tol`` of body weight at the original timing (flight: the body model's momentum
    is not exactly ballistic; stance: the feet cannot push that way) — the polygon allows them that
    residual (see ``polygons.feasible_polygons``). ``unexplained_stance_fraction`` /
    ``unexplained_flight_fraction``: their share of the frames with / without a foot in contact
    (a stance frame unexplained hints at a missed contact; a flight frame never has one to find:
    it measures how far the body model's centre of mass is from ballistic). O(F · nv).
    """
    polys, orig, body = plan.polygons, plan.original, plan.body
    weight = body.total_mass * float(np.linalg.norm(body.default_gravity()))
    names = body.skeleton.names
    # the derivative fit's reach at the default smoothing (RetimeParams holds it; the plan does not carry it)
    half = max(1, round(RetimeParams.model_fields["smoothing_s"].default * plan.motion.fps))
    outside = []
    for i in np.flatnonzero(~polys.original_inside).tolist():
        over = np.abs(orig.tau[i, N_ROOT:]) > orig.limits[N_ROOT:] * (1 + 1e-9)
        if over.any():
            k = int(np.argmax(np.abs(orig.tau[i, N_ROOT:]) / np.maximum(orig.limits[N_ROOT:], 1e-12)))
            j = next(j for j in range(1, body.n_bodies) if body.joint_dofs(j).start <= k + N_ROOT < body.joint_dofs(j).stop)
            need, limit = abs(orig.tau[i, N_ROOT + k]), orig.limits[N_ROOT + k]
            digits = 0 if limit >= 100 else 1
            why = f"joint {names[j]} needs {need:.{digits}f} N·m, over its limit {limit:.{digits}f}"
            # the torque of j carries its subtree's accelerations: look for the jump there
            sub = [int(c) - 1 for c in body.model.subtrees[j + 1]]  # Pinocchio joint c is skeleton joint c - 1
            deg, at, g = max(largest_step(plan.motion.rotations[:, c], i, half) + (c,) for c in sub)
            if deg * plan.motion.fps > GLITCH_DEG_PER_S:
                why += (f"; the data turns {names[g]} {deg:.0f}° from frame {at - 1} to {at} "
                        f"({deg * plan.motion.fps:,.0f}°/s): likely a capture glitch")
        else:
            why = "root force beyond the tolerance of the polygon"
        outside.append({"frame": i, "why": why})
    unexplained = []
    for i in np.flatnonzero(orig.residual > unexplained_tol * weight).tolist():
        feet = [f.name for f, a in zip(plan.contacts.feet, plan.contacts.active[i], strict=True) if a]
        share = orig.residual[i] / weight
        why = (f"flight: the body model's momentum departs from ballistic by {share:.0%} of body weight" if not feet
               else f"contact ({', '.join(feet)}) cannot supply the root force: {share:.0%} of body weight left")
        unexplained.append({"frame": i, "why": why})
    bad = orig.residual > unexplained_tol * weight
    stance = plan.contacts.active.any(axis=1)
    return {"inside_fraction": float(polys.original_inside.mean()) if len(polys.original_inside) else 1.0,
            "outside": outside, "unexplained_fraction": len(unexplained) / max(len(orig.residual), 1),
            "unexplained_stance_fraction": float(bad[stance].mean()) if stance.any() else 0.0,
            "unexplained_flight_fraction": float(bad[~stance].mean()) if (~stance).any() else 0.0,
            "unexplained": unexplained}


def reachability(plan: RetimePlan, res: RetimeResult, outside: int) -> dict[str, Any]:
    """Whether the requested timing was met, with the shortest duration reachable inside the polygons.

    Met: at most ``MET_OUTSIDE_FRACTION`` (10 %) of the output frames (``outside`` of them) lie
    outside their feasible polygon. A duration below the shortest timing inside every polygon
    (:func:`.reachable.fastest_timing`) must leave them somewhere, and the message says by how
    much; where no timing stays inside every polygon it names the frames where the chain breaks
    and ``shortest_feasible_duration`` is None.
    """
    fastest = fastest_timing(plan.polygons, plan.motion.fps)
    bound = fastest.duration
    dur = float(res.t[-1])
    n = len(res.t)
    met = outside <= MET_OUTSIDE_FRACTION * n
    word = "met" if met else "not met"
    if not fastest.inside:
        where = ", ".join(str(i) for i in fastest.broken[:5]) + (" ..." if len(fastest.broken) > 5 else "")
        msg = (f"{word}: no timing stays inside every polygon (no way on inside from source frames {where}); "
               f"{outside} of {n} output frames lie outside theirs")
    elif dur < bound:
        msg = (f"{word if met else 'unreachable'}: {dur:.3f} s is shorter than the shortest duration any timing "
               f"inside the feasible polygons can reach, {bound:.3f} s; the result leaves its polygons on "
               f"{outside} of {n} frames")
    elif not met:
        msg = (f"not met physically: {outside} of {n} output frames lie outside their feasible polygon "
               f"(the shortest timing inside every polygon lasts {bound:.3f} s)")
    else:
        msg = f"met: {n - outside} of {n} output frames inside their polygon (shortest reachable {bound:.3f} s)"
    return {"met": bool(met), "requested_duration": dur,
            "shortest_feasible_duration": bound if fastest.inside else None, "message": msg}


def report(plan: RetimePlan, res: RetimeResult) -> dict[str, Any]:
    """JSON-able report: per output frame timing, torques, contact forces, feasibility; summary.

    Infeasible frames are listed, never hidden: source frames the contact model cannot explain
    (at any timing) and output frames whose (p̈, ṗ²) lies outside its frame's polygon.
    """
    m, obj, cont = plan.motion, plan.baked, plan.contacts
    edges = pyramid_edges(cont, plan.body.up_axis)  # (3, 4)
    source, distance, inside = timing_distances(plan.polygons, m.fps, res.p, res.pd, res.pdd)
    frames = []
    for k in range(len(res.t)):
        x = np.array([res.pdd[k], res.pd[k] ** 2])
        i = int(source[k])
        lam = contact_lambda(obj, i, x)
        tau = plan.A[i] * x[0] + plan.B[i] * x[1] + plan.C[i] - cont.basis[i] @ lam
        forces = {}
        for fi, foot in enumerate(cont.feet):
            if cont.active[i, fi]:
                per = cont.corners * EDGES_PER_CORNER
                lf = lam[fi * per:(fi + 1) * per].reshape(cont.corners, EDGES_PER_CORNER)
                forces[foot.name] = (edges @ lf.sum(axis=0)).round(4).tolist()
        frames.append({"t": round(float(res.t[k]), 6), "source_time": round(float(res.p[k]), 6),
                       "speed": round(float(res.pd[k]), 6), "accel": round(float(res.pdd[k]), 6),
                       "source_frame": i, "feasible": bool(inside[k]), "distance": round(float(distance[k]), 6),
                       "torques": tau[N_ROOT:].round(4).tolist(), "root_residual": tau[:N_ROOT].round(4).tolist(),
                       "contact_forces": forces})
    outside = np.flatnonzero(~inside).tolist()
    fall = free_fall(plan)
    flights = []
    for s0, s1 in inner_flights(cont.active, m.fps):
        o0, o1 = output_time(res, s0), output_time(res, s1)
        flights.append({"source": [s0, s1], "output": [o0, o1], "source_duration": s1 - s0,
                        "output_duration": o1 - o0, "ratio": (o1 - o0) / (s1 - s0),
                        "falls_at": fall["per_flight"].get(s0), "held_up": held_up(fall, s0)})
    polys = plan.polygons
    reach = reachability(plan, res, len(outside))
    return {
        "clip": m.name, "frames_in": m.n_frames, "frames_out": len(res.t), "fps": m.fps,
        "duration_in": m.duration, "duration_out": float(res.t[-1]),
        "gravity": plan.gravity.tolist(), "mass_factors": dict(zip(plan.body.skeleton.names,
                                                                   plan.factors.round(6).tolist(), strict=True)),
        "weight_factors": dict(zip(plan.body.skeleton.names, plan.weight_factors.round(6).tolist(), strict=True)),
        "total_mass_kg": plan.body.total_mass,
        "timing": res.kind, "timing_note": res.message,
        "objective": float(res.objective), "converged": res.converged, "iterations": res.iterations,
        "contacts": cont.intervals(m.fps), "contacts_detected": cont.detected, "flights": flights,
        "phase_seconds": {k: {"source": s, "output": o} for k, (s, o) in phase_times(cont, res, m.fps).items()},
        "infeasible_source_frames": np.flatnonzero(polys.infeasible).tolist(),
        "original_timing_outside_polygon": np.flatnonzero(~polys.original_inside).tolist(),
        "glitches_mended": [g.describe() for g in plan.glitches],
        "infeasible_output_frames": outside,
        "root_residual_source": polys.residual.round(4).tolist(),
        "torque_limits": {n: {"limit": float(plan.original.limits[plan.body.joint_dofs(j).start]),
                              "source": plan.limit_sources.get(n, "")}
                          for j, n in enumerate(plan.body.skeleton.names) if j},
        "original_timing": original_feasibility(plan),
        "free_fall": {k: v for k, v in fall.items() if k != "per_flight"},
        "shortest_feasible_duration": reach["shortest_feasible_duration"],
        "reachable": reach,
        "timings_s": {**plan.timings, "optimize": res.seconds},
        "frames": frames,
    }


def pyramid_edges(cont: Contacts, up_axis: int) -> np.ndarray:
    up = np.zeros(3)
    up[up_axis] = 1.0
    return pyramid(up, cont.friction)
