"""Path dynamics and contact bases (MPS06 §3.1-3.2) on a tiny synthetic jumper."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from motionweb.store.kinematics import quat_from_axis_angle
from motionweb.store.motion import Motion, Skeleton
from motionweb.tasks.contacts import contacts_for, find_feet, pyramid
from motionweb.tasks.dynamics import body_model_for, build_body_model, dynamics_terms, mass_factors

G = 9.81
THIGH = SHANK = 0.45


def jumper_skeleton() -> Skeleton:
    """Pelvis, chest and two 3-joint legs (hip, knee, ankle with a toe end site), metres, Y up."""
    names = ("pelvis", "chest", "l_hip", "l_knee", "l_ankle", "r_hip", "r_knee", "r_ankle")
    parents = np.array([-1, 0, 0, 2, 3, 0, 5, 6])
    offsets = np.array([[0, 0, 0], [0, 0.3, 0], [0.1, -0.05, 0], [0, -THIGH, 0], [0, -SHANK, 0],
                        [-0.1, -0.05, 0], [0, -THIGH, 0], [0, -SHANK, 0]], dtype=float)
    rot = ("Zrotation", "Xrotation", "Yrotation")
    channels = (("Xposition", "Yposition", "Zposition") + rot,) + (rot,) * 7
    ends = {1: np.array([0, 0.4, 0.0]), 4: np.array([0, -0.05, 0.15]), 7: np.array([0, -0.05, 0.15])}
    return Skeleton(names, parents, offsets, channels, ends)


def _hermite(y0: float, v0: float, y1: float, v1: float, T: float, t: np.ndarray) -> np.ndarray:
    s = t / T
    h00, h10 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s
    h01, h11 = -2 * s**3 + 3 * s**2, s**3 - s**2
    return h00 * y0 + h10 * T * v0 + h01 * y1 + h11 * T * v1


def synthetic_jump(fps: float = 40.0, g: float = G, v0: float = 2.0, stand: float = 0.4, bend: float = 0.4
                   ) -> tuple[Motion, tuple[float, float]]:
    """An in-place jump whose flight is exactly ballistic under gravity ``g`` (pose frozen in flight).

    Returns the motion and the flight interval (take-off, landing) in seconds.
    """
    y_stand, y_low, y_off = 0.95, 0.75, 0.98
    phases = [stand, bend, 0.3, 2 * v0 / g, 0.3, bend, stand]
    ends = np.cumsum(phases)
    n = int(np.floor(ends[-1] * fps)) + 1
    t = np.arange(n) / fps
    y = np.empty(n)
    for i, ti in enumerate(t):
        k = int(np.searchsorted(ends, ti, side="right"))
        k = min(k, len(phases) - 1)
        s = ti - (ends[k - 1] if k else 0.0)
        y[i] = [lambda s: y_stand,
                lambda s: _hermite(y_stand, 0, y_low, 0, phases[1], s),
                lambda s: _hermite(y_low, 0, y_off, v0, phases[2], s),
                lambda s: y_off + v0 * s - 0.5 * g * s * s,
                lambda s: _hermite(y_off, -v0, y_low, 0, phases[4], s),
                lambda s: _hermite(y_low, 0, y_stand, 0, phases[5], s),
                lambda s: y_stand][k](s)
    takeoff, landing = ends[2], ends[3]
    # legs: ankle 0.05 above the ground under the hip; frozen at the take-off pose in flight
    d = np.where((t > takeoff) & (t < landing), y_off, y) - 0.05 - 0.05
    d = np.minimum(d, THIGH + SHANK - 1e-6)
    knee = np.pi - np.arccos((THIGH**2 + SHANK**2 - d**2) / (2 * THIGH * SHANK))
    hip = knee / 2
    x = np.array([1.0, 0.0, 0.0])
    rot = np.zeros((n, 8, 4))
    rot[..., 0] = 1.0
    for base in (2, 5):
        rot[:, base] = quat_from_axis_angle(x, -hip)
        rot[:, base + 1] = quat_from_axis_angle(x, knee)
        rot[:, base + 2] = quat_from_axis_angle(x, -hip)
    rot[:, 1] = quat_from_axis_angle(x, 0.1 * np.sin(t))  # a little chest sway
    root = np.zeros((n, 3))
    root[:, 1] = y
    motion = Motion(jumper_skeleton(), fps, root, rot, name="synthetic_jump", unit="m")
    return motion, (float(takeoff), float(landing))


def test_coefficients_reproduce_rnea_with_contacts() -> None:
    motion, _ = synthetic_jump()
    body = body_model_for(motion)
    terms = dynamics_terms(body, motion)
    g = body.default_gravity()
    A, B, C = terms.combine(g)
    cont = contacts_for(body, terms.q, motion.fps)
    m = body.model
    m.gravity = pin.Motion(np.concatenate([g, np.zeros(3)]))
    d = m.createData()
    rng = np.random.default_rng(0)
    for i in rng.choice(motion.n_frames, 8, replace=False):
        pdd, pd = rng.normal(), rng.uniform(0.2, 2.0)
        lam = rng.uniform(0, 100, cont.basis.shape[2])
        v = terms.dq[i] * pd
        a = terms.ddq[i] * pd**2 + terms.dq[i] * pdd
        # contact forces as external forces: τ = rnea(q, v, a) − Σ Jᵀ f
        ref = pin.rnea(m, d, terms.q[i], v, a) - cont.basis[i] @ lam
        got = A[i] * pdd + B[i] * pd**2 + C[i] - cont.basis[i] @ lam
        np.testing.assert_allclose(got, ref, atol=1e-8, rtol=0)


def test_gravity_and_mass_recombination_match_a_changed_model() -> None:
    motion, _ = synthetic_jump(fps=30)
    body = body_model_for(motion)
    terms = dynamics_terms(body, motion)
    g = np.array([3.0, -4.9, 1.0])
    w = mass_factors(body, {"l_hip": 10.0, "chest": 0.5})
    A, B, C = terms.combine(g, w)
    inertias = [body.model.inertias[j + 1] for j in range(body.n_bodies)]
    inertias = [pin.Inertia(i.mass * k, i.lever.copy(), i.inertia * k) for i, k in zip(inertias, w, strict=True)]
    heavy = build_body_model(body.skeleton, 1.0, inertias=inertias)
    m = heavy.model
    m.gravity = pin.Motion(np.concatenate([g, np.zeros(3)]))
    d = m.createData()
    for i in (0, 10, 25, motion.n_frames - 1):
        zero = np.zeros(m.nv)
        np.testing.assert_allclose(A[i], pin.rnea(m, d, terms.q[i], zero, terms.dq[i])
                                   - pin.rnea(m, d, terms.q[i], zero, zero), atol=1e-9)
        np.testing.assert_allclose(C[i], pin.rnea(m, d, terms.q[i], zero, zero), atol=1e-9)
        np.testing.assert_allclose(B[i] + C[i], pin.rnea(m, d, terms.q[i], terms.dq[i], terms.ddq[i]),
                                   atol=1e-9)
    with pytest.raises(ValueError, match="no joint"):
        mass_factors(body, {"tail": 2.0})


def test_flight_is_ballistic_and_stance_detected() -> None:
    motion, (t0, t1) = synthetic_jump()
    body = body_model_for(motion)
    terms = dynamics_terms(body, motion)
    _, B, C = terms.combine(body.default_gravity())
    t = np.arange(motion.n_frames) / motion.fps
    flight = (t > t0 + 1.5 / motion.fps) & (t < t1 - 1.5 / motion.fps)
    root = (B + C)[flight, :6]  # at the original timing (p̈, ṗ²) = (0, 1)
    # a nearly frozen pose (slow chest sway) in exact free fall needs almost no root wrench
    assert np.abs(root).max() < 1e-3 * body.total_mass * G
    cont = contacts_for(body, terms.q, motion.fps)
    assert [f.name for f in cont.feet] == ["l_ankle", "r_ankle"]
    assert not cont.active[flight].any()
    assert cont.active[t < t0 - 0.1].all() and cont.active[t > t1 + 0.15].all()


def test_pyramid_is_inscribed_and_feet_have_four_corners() -> None:
    e = pyramid(np.array([0.0, 1.0, 0.0]), 0.5)
    tangential = np.linalg.norm(e[[0, 2]], axis=0)
    np.testing.assert_allclose(tangential / e[1], 0.5)
    feet = find_feet(jumper_skeleton(), 1.0)
    assert all(f.corners.shape == (4, 3) for f in feet)


def test_unknown_unit_is_a_clear_error() -> None:
    motion, _ = synthetic_jump(fps=20)
    from dataclasses import replace
    with pytest.raises(ValueError, match="length unit"):
        body_model_for(replace(motion, unit=None, scale_to_m=None))
