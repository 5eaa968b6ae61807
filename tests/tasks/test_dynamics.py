"""Path dynamics and contact bases (MPS06 §3.1-3.2) on a tiny synthetic jumper."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from fixtures import G, jumper_skeleton, synthetic_jump
from motionweb.store.motion import Skeleton
from motionweb.tasks.retime import ContactParams
from motionweb.tasks.retime.contacts import (
    contacts_for,
    detect_contacts,
    find_feet,
    missed_stances,
    pyramid,
)
from motionweb.tasks.retime.dynamics import (
    SEGMENT_FRACTIONS,
    body_model_for,
    build_body_model,
    configurations,
    dynamics_terms,
    mass_factors,
    path_derivatives,
    segments,
)
from naive import ref_dynamics_terms

#: the contact rule of the stage's defaults (ContactParams holds them; the functions have none of their own)
RULE = ContactParams()


def test_coefficients_reproduce_rnea_with_contacts() -> None:
    motion, _ = synthetic_jump()
    body = body_model_for(motion, kind="cylinders", total_mass=None)
    terms = dynamics_terms(body, motion, smoothing_s=0.0)
    g = body.default_gravity()
    A, B, C = terms.combine(g)
    cont = contacts_for(body, terms.q, motion.fps, rule=RULE, clip=motion.name)
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


def test_per_body_terms_equal_the_five_regressor_reference() -> None:
    """Two contracted regressors and the centre-of-mass Jacobians give the per-body terms of five
    full regressors (tests/naive.py), on a jumper turned and bent at random."""
    from dataclasses import replace

    motion, _ = synthetic_jump(fps=60)
    rng = np.random.default_rng(3)
    rot = motion.rotations + rng.normal(0, 0.2, motion.rotations.shape)
    motion = replace(motion, rotations=rot / np.linalg.norm(rot, axis=-1, keepdims=True))
    body = body_model_for(motion, kind="table", total_mass=70.0)
    terms = dynamics_terms(body, motion, smoothing_s=0.05)
    a, b, c = ref_dynamics_terms(body, terms.q, terms.dq, terms.ddq)
    np.testing.assert_allclose(terms.a, a, atol=1e-9 * np.abs(a).max())
    np.testing.assert_allclose(terms.b, b, atol=1e-9 * np.abs(b).max())
    np.testing.assert_allclose(terms.c, c, atol=1e-9 * np.abs(c).max())


def test_gravity_and_mass_recombination_match_a_changed_model() -> None:
    motion, _ = synthetic_jump(fps=30)
    body = body_model_for(motion, kind="cylinders", total_mass=None)
    terms = dynamics_terms(body, motion, smoothing_s=0.0)
    g = np.array([3.0, -4.9, 1.0])
    w = mass_factors(body, {"l_hip": 10.0, "chest": 0.5})
    A, B, C = terms.combine(g, w)
    inertias = [body.model.inertias[j + 1] for j in range(body.n_bodies)]
    inertias = [pin.Inertia(i.mass * k, i.lever.copy(), i.inertia * k) for i, k in zip(inertias, w, strict=True)]
    heavy = build_body_model(body.skeleton, 1.0, kind="cylinders", total_mass=None, inertias=inertias)
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


def test_a_weight_factor_changes_only_the_gravity_load() -> None:
    """combine's weight factors (MPS06 Fig. 11's "weight multiplied by ten"): C is that of a model
    whose bodies weigh mass x weight factor, A and B keep the mass factors' inertia."""
    motion, _ = synthetic_jump(fps=30)
    body = body_model_for(motion, kind="cylinders", total_mass=None)
    terms = dynamics_terms(body, motion, smoothing_s=0.0)
    g = np.array([0.5, -9.81, 0.0])
    w = mass_factors(body, {"chest": 2.0})
    wf = mass_factors(body, {"l_hip": 10.0, "chest": 0.5})
    A0, B0, _ = terms.combine(g, w)
    A, B, C = terms.combine(g, w, wf)
    np.testing.assert_array_equal(A, A0)
    np.testing.assert_array_equal(B, B0)
    inertias = [body.model.inertias[j + 1] for j in range(body.n_bodies)]
    loaded = build_body_model(body.skeleton, 1.0, kind="cylinders", total_mass=None, inertias=[pin.Inertia(i.mass * k, i.lever.copy(), i.inertia * k)
                                                            for i, k in zip(inertias, w * wf, strict=True)])
    m = loaded.model
    m.gravity = pin.Motion(np.concatenate([g, np.zeros(3)]))
    d = m.createData()
    for i in (0, 12, motion.n_frames - 1):
        np.testing.assert_allclose(C[i], pin.rnea(m, d, terms.q[i], np.zeros(m.nv), np.zeros(m.nv)), atol=1e-9)
    assert np.abs(C - terms.combine(g, w)[2]).max() > 1.0


def test_flight_is_ballistic_and_stance_detected() -> None:
    motion, (t0, t1) = synthetic_jump()
    body = body_model_for(motion, kind="cylinders", total_mass=None)
    terms = dynamics_terms(body, motion, smoothing_s=0.0)
    _, B, C = terms.combine(body.default_gravity())
    t = np.arange(motion.n_frames) / motion.fps
    flight = (t > t0 + 1.5 / motion.fps) & (t < t1 - 1.5 / motion.fps)
    root = (B + C)[flight, :6]  # at the original timing (p̈, ṗ²) = (0, 1)
    # a nearly frozen pose (slow chest sway) in exact free fall needs almost no root wrench
    assert np.abs(root).max() < 1e-3 * body.total_mass * G
    cont = contacts_for(body, terms.q, motion.fps, rule=RULE, clip=motion.name)
    assert [f.name for f in cont.feet] == ["l_ankle", "r_ankle"]
    assert not cont.active[flight].any()
    assert cont.active[t < t0 - 0.1].all() and cont.active[t > t1 + 0.15].all()


def test_pyramid_is_inscribed_and_feet_have_four_corners() -> None:
    e = pyramid(np.array([0.0, 1.0, 0.0]), 0.5)
    tangential = np.linalg.norm(e[[0, 2]], axis=0)
    np.testing.assert_allclose(tangential / e[1], 0.5)
    feet = find_feet(jumper_skeleton(), 1.0)
    assert all(f.corners.shape == (4, 3) for f in feet)


def test_feet_with_toes_stand_on_a_forefoot_patch_when_the_heel_is_up() -> None:
    """A foot joint with a toe segment gets a corner pair across the ball (the toe joint): with the
    heel up the toe tips and the ball push — a patch from the ball to the tips — not the line of
    the tips; a heel alone down pushes with the heel."""
    from motionweb.store.motion import Skeleton
    from motionweb.tasks.retime.contacts import BALL, HEEL, TOE

    base = jumper_skeleton()
    names = base.names + ("l_toes", "r_toes")
    parents = np.append(base.parents, [4, 7])
    toe = np.array([0.0, -0.04, 0.12])  # ankle -> ball of the foot
    offsets = np.vstack([base.offsets, toe, toe])
    ends = {1: base.end_sites[1], 8: np.array([0.0, 0.0, 0.06]), 9: np.array([0.0, 0.0, 0.06])}
    sk = Skeleton(names, parents, offsets, base.channels + (base.channels[1],) * 2, ends)
    feet = find_feet(sk, 1.0)
    assert [f.name for f in feet] == ["l_ankle", "r_ankle"] and all(f.corners.shape == (6, 3) for f in feet)
    c = feet[0].corners
    along = c[:, 2]
    np.testing.assert_allclose(along[list(TOE)], 0.18)  # the toe tips
    np.testing.assert_allclose(along[list(BALL)], 0.12)  # the toe joint
    np.testing.assert_allclose(along[list(HEEL)], -0.25 * 0.18)
    assert np.ptp(c[:, 1]) < 1e-12  # one sole plane
    fps = 120.0
    track = np.repeat(np.repeat(c[None, None], 60, axis=0), 1, axis=1)  # (F, 1, 6, 3), standing still
    track[..., 1] -= c[:, 1].min()
    up = track.copy()
    up[:, :, list(HEEL), 1] = 0.1  # heel raised: on the ball and the toes
    act, corner, _ = detect_contacts(up, fps, rule=RULE, floor=0.0)
    assert act.all() and corner[:, 0, list(TOE) + list(BALL)].all() and not corner[:, 0, list(HEEL)].any()
    heel = track.copy()
    heel[:, :, list(TOE) + list(BALL), 1] = 0.1  # toes raised (heel strike): the heel only
    act, corner, _ = detect_contacts(heel, fps, rule=RULE, floor=0.0)
    assert act.all() and corner[:, 0, list(HEEL)].all() and not corner[:, 0, list(TOE) + list(BALL)].any()
    # the support of the forefoot: a patch as long as the toes, where the tips alone gave a line
    pts = c[list(TOE) + list(BALL)][:, [0, 2]]
    assert np.ptp(pts[:, 1]) == pytest.approx(0.06) and np.ptp(pts[:, 0]) > 0.05


def test_unknown_unit_is_a_clear_error() -> None:
    motion, _ = synthetic_jump(fps=20)
    from dataclasses import replace
    with pytest.raises(ValueError, match="length unit"):
        body_model_for(replace(motion, unit=None, scale_to_m=None), kind="cylinders", total_mass=None)


def test_path_derivatives_fit_a_quadratic_exactly_and_reduce_to_central_differences() -> None:
    motion, _ = synthetic_jump(fps=120)
    t = np.arange(motion.n_frames) / motion.fps
    root = motion.root_positions.copy()
    root[:, 1] = 0.9 + 0.3 * t - 2.0 * t * t  # a quadratic path: every window fits it exactly
    rot = np.repeat(motion.rotations[:1], motion.n_frames, axis=0)
    from dataclasses import replace

    body = body_model_for(motion, kind="cylinders", total_mass=None)
    q = configurations(body, replace(motion, root_positions=root, rotations=rot))
    d1, d2 = path_derivatives(body, q, motion.fps, smoothing_s=0.04)  # ±5 frames
    np.testing.assert_allclose(d2[:, 1], -4.0, atol=1e-6)
    np.testing.assert_allclose(d1[:, 1], 0.3 - 4.0 * t, atol=1e-6)
    # m = 1: the central difference on the manifold
    q = configurations(body, motion)
    d1, d2 = path_derivatives(body, q, motion.fps, smoothing_s=0.0)
    h = 1 / motion.fps
    for i in (1, 50, motion.n_frames - 2):
        fwd, bwd = pin.difference(body.model, q[i], q[i + 1]), pin.difference(body.model, q[i], q[i - 1])
        np.testing.assert_allclose(d1[i], (fwd - bwd) / (2 * h), atol=1e-9)
        np.testing.assert_allclose(d2[i], (fwd + bwd) / h**2, atol=1e-6)


def test_path_derivatives_keep_a_full_window_at_the_clip_ends() -> None:
    """Within m frames of an end the fit uses the 2m + 1 frames nearest it (scipy's savgol_filter
    mode="interp", the reference here): q'' there is as noisy as in the interior, where a window
    cut at the end would extrapolate a quadratic fitted to m + 1 frames (26x the variance)."""
    from dataclasses import replace

    from scipy.signal import savgol_filter

    motion, _ = synthetic_jump(fps=120)
    f, h, w = motion.n_frames, 1 / motion.fps, 10
    t = np.arange(f) * h
    rng = np.random.default_rng(3)
    rot = np.repeat(motion.rotations[:1], f, axis=0)
    rot[:, 0] = [1.0, 0.0, 0.0, 0.0]  # root not turning: its tangent offsets are the world translations
    body = body_model_for(motion, kind="cylinders", total_mass=None)
    err_end, err_mid = [], []
    for _ in range(4):
        root = np.stack([0.5 * t, 0.9 + 0.3 * t - 2.0 * t * t, 0.1 * t * t], axis=1) + rng.normal(0, 1e-3, (f, 3))
        q = configurations(body, replace(motion, root_positions=root * body.scale ** -1, rotations=rot))
        d1, d2 = path_derivatives(body, q, motion.fps, smoothing_s=w * h)
        ref = q[:, :3]
        np.testing.assert_allclose(d2[:, :3], savgol_filter(ref, 2 * w + 1, 2, deriv=2, delta=h, axis=0, mode="interp"),
                                   atol=1e-6)
        np.testing.assert_allclose(d1[:, :3], savgol_filter(ref, 2 * w + 1, 2, deriv=1, delta=h, axis=0, mode="interp"),
                                   atol=1e-8)
        truth = np.array([0.0, -4.0, 0.2])
        err_end.append(np.r_[d2[:w, :3], d2[-w:, :3]] - truth)
        err_mid.append(d2[w:-w, :3] - truth)
    ratio = np.std(np.concatenate(err_end)) / np.std(np.concatenate(err_mid))
    assert 0.5 < ratio < 1.6, ratio


def test_table_body_model_gives_an_adult_its_segment_masses() -> None:
    motion, _ = synthetic_jump()
    body = body_model_for(motion, kind="table", total_mass=70.0)
    seg = dict(zip(motion.skeleton.names, segments(motion.skeleton, 1.0), strict=True))
    assert seg == {"pelvis": "pelvis", "chest": "head_neck", "l_hip": "thigh", "l_knee": "shank", "l_ankle": "foot",
                   "r_hip": "thigh", "r_knee": "shank", "r_ankle": "foot"}
    m = dict(zip(motion.skeleton.names, body.masses, strict=True))
    assert body.total_mass == pytest.approx(70.0)
    # no arms or torso in this skeleton: the shares present are renormalized, ratios kept
    assert m["l_hip"] / m["l_knee"] == pytest.approx(SEGMENT_FRACTIONS["thigh"] / SEGMENT_FRACTIONS["shank"])
    assert m["l_hip"] == pytest.approx(m["r_hip"]) and m["l_ankle"] == pytest.approx(m["r_ankle"])
    assert sum(SEGMENT_FRACTIONS[s] * (1 if s in ("pelvis", "torso", "head_neck") else 2)
               for s in SEGMENT_FRACTIONS) == pytest.approx(1.0)


def _humanoid(clavicle: float, forearm: float, thigh: float, shank: float) -> Skeleton:
    """A T-posed humanoid, y up: legs hip → knee → ankle → toe, spine → chest → neck → head,
    arms clavicle → shoulder → elbow → wrist; body j spans joint j to its child."""
    joints: list[tuple[str, int, tuple[float, float, float]]] = [("hips", -1, (0.0, 1.0, 0.0))]
    for side, x in (("l", 1.0), ("r", -1.0)):
        k = len(joints)
        joints += [(f"{side}hip", 0, (0.1 * x, -0.05, 0.0)), (f"{side}knee", k, (0.0, -thigh, 0.0)),
                   (f"{side}ankle", k + 1, (0.0, -shank, 0.0)), (f"{side}toe", k + 2, (0.0, -0.05, 0.12))]
    k = len(joints)
    joints += [("spine", 0, (0.0, 0.1, 0.0)), ("chest", k, (0.0, 0.25, 0.0)), ("neck", k + 1, (0.0, 0.25, 0.0)),
               ("head", k + 2, (0.0, 0.1, 0.0))]
    chest = k + 1
    for side, x in (("l", 1.0), ("r", -1.0)):
        k = len(joints)
        joints += [(f"{side}clavicle", chest, (0.0, 0.22, 0.0)), (f"{side}shoulder", k, (clavicle * x, 0.0, 0.0)),
                   (f"{side}elbow", k + 1, (0.30 * x, 0.0, 0.0)), (f"{side}wrist", k + 2, (forearm * x, 0.0, 0.0))]
    names = tuple(n for n, _, _ in joints)
    ends = {names.index(n): np.array(e) for n, e in (("ltoe", (0.0, 0.0, 0.05)), ("rtoe", (0.0, 0.0, 0.05)),
                                                      ("head", (0.0, 0.2, 0.0)), ("lwrist", (0.08, 0.0, 0.0)),
                                                      ("rwrist", (-0.08, 0.0, 0.0)))}
    channels = tuple(("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation") if p < 0
                     else ("Zrotation", "Xrotation", "Yrotation") for _, p, _ in joints)
    return Skeleton(names, np.array([p for _, p, _ in joints]), np.array([o for _, _, o in joints]), channels, ends)


@pytest.mark.parametrize("clavicle, forearm", [(0.15, 0.25), (0.20, 0.18)])
def test_segments_follow_the_limbs_whatever_their_proportions(clavicle: float, forearm: float) -> None:
    """The upper arm is the arm's longest body, the forearm the longest after it, though the
    clavicle outgrows the forearm (CMU subjects 14 and 135); a shank longer than its thigh."""
    sk = _humanoid(clavicle, forearm, thigh=0.40, shank=0.44)
    seg = dict(zip(sk.names, segments(sk, 1.0), strict=True))
    for side in "lr":
        assert [seg[f"{side}{n}"] for n in ("hip", "knee", "ankle", "toe")] == ["thigh", "shank", "foot", "foot"]
        assert [seg[f"{side}{n}"] for n in ("clavicle", "shoulder", "elbow", "wrist")] == \
            ["shoulder", "upper_arm", "forearm", "hand"]
    assert seg["hips"] == "pelvis" and seg["spine"] == "torso" and seg["head"] == "head_neck"


def test_a_flight_that_does_not_fall_is_a_missed_stance() -> None:
    """missed_stances: frames with no foot detected where the centre of mass stands still (not a
    fall at g) are carried by the lower foot if it hovers within height_off, slow (CMU 16_29's
    pivot at 4.5 cm); a foot at 9 cm is not put down, nor is a real (ballistic) flight."""
    motion, (t0, t1) = synthetic_jump(fps=30)
    body = body_model_for(motion, kind="cylinders", total_mass=None)
    q = configurations(body, motion)
    fps, f = motion.fps, motion.n_frames
    still = slice(10, 22)  # standing: the centre of mass does not move
    flight = slice(int(np.ceil(t0 * fps)) + 1, int(np.floor(t1 * fps)))
    for frames, hover, mended in ((still, 0.045, True), (still, 0.09, False), (flight, 0.045, False)):
        heights = np.zeros((f, 2))
        heights[frames] = [hover, 0.2]
        pos = np.concatenate([_foot_track(heights[:, k], fps) for k in range(2)], axis=1)
        active = heights < 0.01
        corner = np.repeat(active[:, :, None], 4, axis=2)
        act, cor, runs_put = missed_stances(body, q, pos, active, corner, 0.0, fps, RULE)
        if mended:
            assert runs_put == [(frames.start, frames.stop, 0)]
            assert act[frames, 0].all() and cor[frames, 0].all() and not act[frames, 1].any()
        else:
            assert runs_put == [] and not act[frames].any()


def _foot_track(heights: np.ndarray, fps: float, speed: float = 0.0) -> np.ndarray:
    """(F, 1, 4, 3) sole corners of one flat foot at ``heights`` moving forward at ``speed``."""
    f = len(heights)
    pos = np.zeros((f, 1, 4, 3))
    pos[..., 1] = heights[:, None, None]
    pos[..., 0] = np.array([0.2, 0.2, 0.0, 0.0]) + speed * np.arange(f)[:, None, None] / fps
    pos[..., 2] = np.array([0.05, -0.05, -0.05, 0.05])
    return pos


def test_contacts_use_the_clips_floor_hysteresis_and_minimum_durations() -> None:
    fps = 120.0
    rng = np.random.default_rng(0)
    h = np.full(240, 0.3)
    h[:100] = 0.0
    h[140:] = 0.0
    h[40:42] = 0.06  # a 2-frame marker glitch: between height_on and height_off, so held by hysteresis
    h[70:72] = 0.2  # a 2-frame lift: a gap shorter than gap_s, closed
    h[:140] += rng.normal(0, 0.004, 140).clip(-0.01, 0.01)
    h += 0.12  # the floor of this capture is 12 cm up
    act, corner, floor = detect_contacts(_foot_track(h, fps), fps, rule=RULE, floor=None)
    assert floor == pytest.approx(0.12, abs=0.012)
    a = act[:, 0]
    # 99 and 140 are the last / first frames on the floor: still on one side (one-sided speeds)
    assert a[:100].all() and not a[100:140].any() and a[140:].all()
    assert corner[a, 0].all()  # a flat foot: toe and heel
    # a 3-frame touch is shorter than min_s and is dropped; a fixed floor replaces the clip's
    h2 = np.full(120, 0.5)
    h2[60:63] = 0.0
    act2, _, floor2 = detect_contacts(_foot_track(h2, fps), fps, rule=RULE, floor=0.0)
    assert floor2 == 0.0 and not act2.any()
    # a foot sliding fast a few cm up is not in contact; on the floor it is (skating, pivoting)
    act3, _, _ = detect_contacts(_foot_track(np.full(60, 0.025), fps, speed=3.0), fps, rule=RULE, floor=0.0)
    assert not act3.any()
    act3, _, _ = detect_contacts(_foot_track(np.full(60, 0.005), fps, speed=3.0), fps, rule=RULE, floor=0.0)
    assert act3.all()
    # heel up: only the toe corners push
    tilt = _foot_track(np.zeros(60), fps)
    tilt[:, :, 2:, 1] = 0.1
    act4, corner4, _ = detect_contacts(tilt, fps, rule=RULE, floor=0.0)
    assert act4.all() and corner4[:, 0, :2].all() and not corner4[:, 0, 2:].any()
