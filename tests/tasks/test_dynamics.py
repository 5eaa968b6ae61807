"""Path dynamics and contact bases (MPS06 §3.1-3.2) on a tiny synthetic jumper."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from fixtures import G, jumper_skeleton, synthetic_jump
from motionweb.tasks.retime.contacts import contacts_for, find_feet, pyramid
from motionweb.tasks.retime.dynamics import body_model_for, build_body_model, dynamics_terms, mass_factors


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
