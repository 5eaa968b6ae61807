"""Physics-based retiming end to end: parameters, prepared plan, retimed motion (design §8, MPS06 §3).

:func:`prepare` runs the stages that depend on the clip and the physics only — body model and path
dynamics (:mod:`.dynamics`), contacts (:mod:`.contacts`), original forces and feasible polygons
(:mod:`.polygons`), the baked objective (:mod:`.objective`) — and :func:`retime_plan` optimizes a
timing for one duration and keytimes (:mod:`.spline`), so one plan serves many timings.

Costs: polygons O(F · n_LP · LP), baking O(F · K · nv · nλ), one objective evaluation O(S · K).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from motionweb.store.kinematics import sample_motion
from motionweb.store.motion import Motion, Skeleton
from motionweb.tasks.params.retime import RetimeParams
from motionweb.tasks.retime.contacts import Contacts, contacts_for
from motionweb.tasks.retime.dynamics import (
    BodyModel,
    DynamicsTerms,
    body_model_for,
    configurations,
    dynamics_terms,
    mass_factors,
)
from motionweb.tasks.retime.errors import RetimeError
from motionweb.tasks.retime.glitches import Glitch, repair_glitches
from motionweb.tasks.retime.limits import joint_torques, table_limits
from motionweb.tasks.retime.objective import BakedObjective, bake
from motionweb.tasks.retime.path_timing import frame_weights, path_timing
from motionweb.tasks.retime.polygons import (
    MET_OUTSIDE_FRACTION,
    N_ROOT,
    FeasiblePolygons,
    OriginalForces,
    feasible_polygons,
    original_forces,
    timing_distances,
)
from motionweb.tasks.retime.spline import RetimeResult, check_keytimes, optimize_timing


@dataclass(frozen=True, eq=False)
class RetimePlan:
    """Everything precomputed for one clip and one physics setting (reused across timings).

    ``A, B, C`` are the recombined path-dynamics terms under the new gravity / masses (``factors``)
    / weights (``weight_factors``, on top of the masses), each (B,) per body; ``original``
    the forces of the unmodified clip (targets of the 'match' objective and torque limits);
    ``glitches`` the capture glitches mended in the path the dynamics are computed from.
    """

    motion: Motion
    body: BodyModel
    terms: DynamicsTerms
    contacts: Contacts
    gravity: np.ndarray
    factors: np.ndarray
    weight_factors: np.ndarray
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    original: OriginalForces
    polygons: FeasiblePolygons
    baked: BakedObjective
    timings: dict[str, float]
    limit_sources: dict[str, str] = field(default_factory=dict)
    glitches: list[Glitch] = field(default_factory=list)


def humanoid_foot_corners(humanoid: Any, skeleton: Skeleton) -> dict[int, np.ndarray]:
    """Sole rectangles ``{joint: (4, 3)}`` (joint frame, m) of a humanoid's foot boxes."""
    out = {}
    for name, box in getattr(humanoid, "foot_boxes", {}).items():
        hx, hy, hz = np.asarray(box.size, float) / 2
        local = np.array([[hx, -hy, hz], [hx, -hy, -hz], [-hx, -hy, -hz], [-hx, -hy, hz]])
        w, v = float(box.rotation[0]), np.asarray(box.rotation[1:], float)
        rot = local + 2 * w * np.cross(v, local) + 2 * np.cross(v, np.cross(v, local))
        out[skeleton.index(name)] = np.asarray(box.origin, float) + rot
    return out


def clip_physics(motion: Motion, opts: RetimeParams, *, up: int = 1, humanoid: Any | None = None,
                 contact_intervals: dict[str, list[tuple[float, float]]] | None = None,
                 timings: dict[str, float] | None = None) -> tuple[BodyModel, list[Glitch], DynamicsTerms, Contacts]:
    """A clip's body model, the capture glitches mended in its path (``opts.repair_glitches``), its
    path dynamics (MPS06 §3.1) and its contacts (§3.2). ``timings`` gets the seconds of the stages
    "dynamics" and "contacts". Cost O(F · nv · B)."""
    tm = timings if timings is not None else {}
    t = time.perf_counter()
    body = body_model_for(motion, kind=opts.body_model, total_mass=opts.total_mass, up_axis=up, humanoid=humanoid)
    path, glitches = repair_glitches(motion) if opts.repair_glitches else (motion, [])
    terms = dynamics_terms(body, path, opts.smoothing_s)
    tm["dynamics"] = time.perf_counter() - t
    t = time.perf_counter()
    contacts = _detect(body, terms.q, motion, opts, humanoid, contact_intervals)
    tm["contacts"] = time.perf_counter() - t
    return body, glitches, terms, contacts


def _detect(body: BodyModel, q: np.ndarray, motion: Motion, opts: RetimeParams, humanoid: Any | None,
            contact_intervals: dict[str, list[tuple[float, float]]] | None) -> Contacts:
    corners = humanoid_foot_corners(humanoid, motion.skeleton) if humanoid is not None else None
    return contacts_for(body, q, motion.fps, rule=opts.contacts, clip=motion.name, intervals=contact_intervals,
                        foot_corners=corners)


def clip_contacts(motion: Motion, opts: RetimeParams, *, up: int = 1) -> Contacts:
    """A clip's foot contacts as :func:`clip_physics` detects them (MPS06 §3.2; the clip's own
    ``opts.contacts.intervals`` win), without its dynamics: what another stage (the guided warp's
    summary) tells flight phases by. O(F · J)."""
    body = body_model_for(motion, kind=opts.body_model, total_mass=opts.total_mass, up_axis=up)
    path, _ = repair_glitches(motion) if opts.repair_glitches else (motion, [])
    return _detect(body, configurations(body, path), motion, opts, None,
                   opts.contacts.intervals.get(motion.name) or None)


def observed_torques(motion: Motion, opts: RetimeParams) -> dict[str, np.ndarray]:
    """Per joint name, (F,) the largest |component| of its torque at the clip's own timing under the
    default physics, contacts carrying their share (min-Σλ, ``polygons.original_forces``): what the
    shipped torque table is observed from (``limits.observed_limits``, MPS06 §4). O(F · nv · B)."""
    body, _, terms, contacts = clip_physics(motion, opts)
    weight = body.total_mass * float(np.linalg.norm(body.default_gravity()))
    orig = original_forces(*terms.combine(body.default_gravity()), contacts, opts.torque_margin, weight,
                           opts.polygons)
    return joint_torques(body, orig.tau)


def prepare(motion: Motion, opts: RetimeParams | None = None, *, up_axis: str = "y", gravity: np.ndarray | None = None,
            mass: dict[str, float] | None = None, humanoid: Any | None = None,
            contact_intervals: dict[str, list[tuple[float, float]]] | None = None,
            weight_factors: dict[str, float] | None = None,
            physics: tuple[BodyModel, list[Glitch], DynamicsTerms, Contacts] | None = None) -> RetimePlan:
    """Dynamics, contacts, original forces, feasible polygons and the baked objective (MPS06 §3.1-3.6).

    ``mass`` multiplies bodies' masses (inertia and weight, MPS06 §3.2: τ is linear in each);
    ``weight_factors`` multiplies only their weight, the gravity load, inertia kept (MPS06 §4.2 Fig. 11:
    "the left femur's weight multiplied by ten"; the CLI's ``--weight``, one name from there to
    ``DynamicsTerms.combine`` and ``RetimePlan.weight_factors``, per body there).
    ``physics``: the clip's :func:`clip_physics` for the same ``opts``, ``up_axis``, ``humanoid``
    and ``contact_intervals``, when the caller keeps it: the path dynamics and contacts do not
    depend on gravity, masses or weights (τ = a p̈ + b ṗ² + c with c linear in gravity and τ linear
    in each body's mass, MPS06 §3.1-3.2), so a physics change skips them (the retime sessions of
    ``motionweb app``); the plan is the same as without it.
    Raises ``RetimeError`` when no foot touches the ground (unless ``allow_flight_only``), and
    ``ValueError`` for an unknown unit or an unknown joint in ``mass`` or ``weight_factors``.
    """
    opts = opts or RetimeParams()
    tm: dict[str, float] = {}
    up = "xyz".index(up_axis)
    if physics is None:
        physics = clip_physics(motion, opts, up=up, humanoid=humanoid, contact_intervals=contact_intervals, timings=tm)
    else:
        tm.update(dynamics=0.0, contacts=0.0)
    body, glitches, terms, contacts = physics
    factors = mass_factors(body, mass or {})
    weight_factors = mass_factors(body, weight_factors or {})  # {joint: factor} -> (B,) per body
    if not contacts.active.any() and not opts.allow_flight_only:
        feet = ", ".join(f.name for f in contacts.feet)
        low = contacts.corner_positions[..., up].min() - contacts.ground
        raise RetimeError(
            f"no ground contact detected in {motion.name or 'the clip'}: feet ({feet}) never come within "
            f"{opts.contacts.height_on} m of the floor at {up_axis}={contacts.ground:.3f} (lowest {low:.3f} m above) "
            f"while slower than {opts.contacts.speed_on} m/s. Give contact intervals (retime.contacts.intervals in "
            "the config), adjust retime.contacts.height_on / floor_height, or set retime.allow_flight_only: true "
            "to retime it as pure flight (ballistic).")
    g0 = body.default_gravity()
    g = g0 if gravity is None else np.asarray(gravity, dtype=float)
    body_weight = body.total_mass * float(np.linalg.norm(g0))
    t = time.perf_counter()
    A0, B0, C0 = terms.combine(g0)
    original = original_forces(A0, B0, C0, contacts, opts.torque_margin, body_weight, opts.polygons)
    sources = {n: "clip peak x torque_margin" for n in body.skeleton.names[1:]}
    if opts.torque_limits_from == "table":
        limits, sources = table_limits(body, opts.torque_limits)
        original = replace(original, limits=limits)
    tm["original_forces"] = time.perf_counter() - t
    A, B, C = terms.combine(g, factors, weight_factors)
    contacts = contacts.carrying(original.tau[:, :N_ROOT])
    polys = feasible_polygons(A, B, C, contacts, original.limits, body_weight, opts.polygons)
    tm["polygons"] = polys.seconds
    t = time.perf_counter()
    sp = opts.spline
    target = original.tau if sp.objective == "match" else np.zeros_like(original.tau)
    if sp.objective not in ("match", "minimize"):
        raise ValueError(f"unknown objective {sp.objective!r} (match, minimize)")
    tau_scale = np.where(np.arange(len(original.limits)) < N_ROOT, body_weight, original.limits)
    baked = bake(polys, A, B, C, contacts, target, sp.alpha, sp.beta, tau_scale)
    tm["bake"] = time.perf_counter() - t
    return RetimePlan(motion=motion, body=body, terms=terms, contacts=contacts, gravity=g, factors=factors,
                      weight_factors=weight_factors, A=A, B=B, C=C, original=original, polygons=polys, baked=baked,
                      timings=tm, limit_sources=sources, glitches=glitches)


def retime_plan(plan: RetimePlan, duration: float, keytimes: list[tuple[float, float]] | None = None,
                opts: RetimeParams | None = None, free_length: bool = False) -> tuple[Motion, RetimeResult]:
    """Time a prepared clip (``opts.spline.timing``: the optimized spline, the path timing, or the spline
    unless it misses the target at another length than the clip's and the path timing leaves fewer
    frames outside) and sample the retimed motion at the source fps.

    ``free_length``: ``duration`` is the starting length and the optimizer picks the length too.
    Raises ``RetimeError`` for timing "path" with keytimes, a free length, or a duration no path
    timing reaches.
    """
    opts = opts or RetimeParams()
    sp, speed_max = opts.spline, opts.polygons.speed_max
    m = plan.motion
    path_ok = not keytimes and not free_length
    if sp.timing == "path" and not path_ok:
        raise RetimeError("retime.spline.timing 'path' takes no keytimes and no free length: use 'spline' or 'auto'")
    res = None
    if sp.timing != "path":
        res = optimize_timing(plan.baked, m.fps, m.duration, duration, keytimes,
                              samples_per_frame=sp.samples_per_frame, knots_per_second=sp.knots_per_second,
                              speed_max=speed_max, free_length=free_length)
    outside = None if res is None else outside_count(plan, res)
    own_length = abs(duration - m.duration) < 0.5 / m.fps  # the path timing would be the original one
    if sp.timing != "spline" and path_ok and (outside is None or (
            outside > MET_OUTSIDE_FRACTION * len(res.t) and not own_length)):
        if res is None:  # the spline's optimizer checks the request otherwise
            check_keytimes(m.duration, duration, [], speed_max)
        path = path_timing(plan.polygons, plan.baked, m.fps, duration, sp.samples_per_frame,
                           frame_weights(plan.contacts.active.any(axis=1)))
        if path is None and res is None:
            raise RetimeError(f"no path timing of {duration:g} s stays inside the feasible polygons on half its "
                              "frames or more: use retime.spline.timing 'spline' or 'auto'")
        if path is not None and (outside is None or outside_count(plan, path) < outside):
            res = path
    out = replace(sample_motion(m, res.p * m.fps), name=f"{m.name}_retimed", source=None, content_hash="")
    return out, res


def outside_count(plan: RetimePlan, res: RetimeResult) -> int:
    """Output frames of a timing outside their feasible polygon (``polygons.timing_distances``)."""
    return int((~timing_distances(plan.polygons, plan.motion.fps, res.p, res.pd, res.pdd)[2]).sum())
