"""Parameterized motion (KG04 §4.2-4.4) on demo reaches and kicks whose targets are known."""

from __future__ import annotations

import numpy as np
import pytest
from motionweb.store.demo.corpus import generate_clip
from motionweb.tasks.blend import keytime_registration, registered_examples
from motionweb.tasks.parameterize import (
    FinalRoot,
    ParameterizeParams,
    build_space,
    dedupe,
    example_params,
    leave_one_out,
    near_convex_weights,
    parse_param,
    redundant_examples,
    satisfies_eq1,
)

RATE = 30.0


def action_keys(truth: dict, label: str) -> np.ndarray:
    """Key times (s) of a demo clip around its action: start, action start, apex, action end, end."""
    a = next(x for x in truth["actions"] if x["label"] == label)
    return np.array([0.0, a["start_s"], a["apex_s"], a["end_s"], truth["duration"]])


def space_of(category: str, label: str, variants: range, same: str):
    clips = [generate_clip(category, v, 7) for v in variants]
    first = clips[0][1]["params"][same]
    clips = [c for c in clips if c[1]["params"][same] == first]
    keys = [action_keys(t, label) for _, t in clips]
    end = min(k[-1] - k[3] for k in keys)  # common tail after the action
    keys = [np.array([*k[:4], k[3] + end]) for k in keys]
    motions = [m for m, _ in clips]
    return motions, [t for _, t in clips], registered_examples(motions, keytime_registration(motions, keys, RATE))


@pytest.fixture(scope="module")
def reaches():
    motions, truths, ex = space_of("reach", "reach", range(24), "side")
    k0 = action_keys(truths[0], "reach")
    hand = truths[0]["targets"][0]["effector"]
    fn = parse_param(f"position:{hand}@{k0[2]:.6f}")
    return truths, ex, fn


def test_eq1_weights_always_hold() -> None:
    rng = np.random.default_rng(0)
    for delta in (0.0, 0.1, 0.5):
        for n in (2, 3, 4, 7):
            w = near_convex_weights(5000, n, delta, rng)
            assert satisfies_eq1(w, delta)
            if delta > 0:
                assert (w < 0).any()  # extrapolation is used
            # every partial sum in the assignment order stays valid, so no weight pins the last
            assert w.min() >= -delta - 1e-12 and w.max() <= 1 + delta + 1e-12


def test_dedupe_keeps_no_pair_closer_than_the_radius() -> None:
    rng = np.random.default_rng(1)
    pts = rng.random((400, 2))
    keep = dedupe(pts, 3, 0.05)
    assert list(keep[:3]) == [0, 1, 2]
    k = pts[keep[3:]]
    d = np.linalg.norm(k[:, None] - np.concatenate([pts[:3], k])[None], axis=-1)
    for i in range(len(k)):
        assert d[i, : 3 + i].min() >= 0.05
    dropped = np.setdiff1d(np.arange(3, 400), keep)
    for i in dropped:  # a dropped point had a kept neighbour before it
        before = keep[keep < i]
        assert np.linalg.norm(pts[before] - pts[i], axis=1).min() < 0.05


def test_parameter_of_each_example_is_its_demo_target(reaches) -> None:
    truths, ex, fn = reaches
    p = example_params(fn, ex)
    target = np.array([t["targets"][0]["position"] for t in truths])
    np.testing.assert_allclose(p, target, atol=0.002)  # the registered apex is the clip's apex


def test_samples_satisfy_eq1_and_reproduce_their_parameters(reaches) -> None:
    _, ex, fn = reaches
    cfg = ParameterizeParams(samples=300, seed=4)
    sp = build_space(fn, ex, cfg)
    assert len(sp.params) > ex.n + 50
    assert satisfies_eq1(sp.weights, cfg.extrapolation)
    np.testing.assert_allclose(sp.params[: ex.n], example_params(fn, ex))
    rows = np.arange(ex.n, len(sp.params), 17)
    dense = np.stack([sp.dense_weights(np.array([r]), np.ones(1)) for r in rows])
    np.testing.assert_allclose(fn(ex, dense), sp.params[rows], atol=1e-12)
    d = np.linalg.norm(sp.params[ex.n:, None] - sp.params[None], axis=-1)
    d[np.arange(len(d)), np.arange(ex.n, len(sp.params))] = np.inf
    assert np.all(d[:, : ex.n].min(axis=1) >= cfg.min_distance)
    again = build_space(fn, ex, cfg)
    np.testing.assert_array_equal(again.params, sp.params)  # seeded


def test_interpolated_weights_stay_valid_and_exact_hits_return_the_sample(reaches) -> None:
    _, ex, fn = reaches
    sp = build_space(fn, ex, ParameterizeParams(samples=300))
    r = ex.n + 5
    w, nearest = sp.weights_for(sp.params[r])
    assert nearest == 0.0
    np.testing.assert_allclose(w, sp.dense_weights(np.array([r]), np.ones(1)))
    rng = np.random.default_rng(2)
    lo, hi = sp.params.min(0), sp.params.max(0)
    for t in lo + (hi - lo) * rng.random((50, 3)):
        w, _ = sp.weights_for(t)
        assert satisfies_eq1(w, sp.cfg.extrapolation)


def test_held_out_reach_targets_are_hit_within_2cm(reaches) -> None:
    """Leave-one-out on the demo reaches: each clip's known wrist target from a space of the
    others, for the targets inside the others' accessible region."""
    truths, ex, fn = reaches
    cfg = ParameterizeParams(samples=600)
    inside = []
    for i in range(ex.n):
        others = np.array([k for k in range(ex.n) if k != i])
        sp = build_space(fn, ex, cfg, others)
        s = sp.synthesize(np.array(truths[i]["targets"][0]["position"]))
        assert np.all(s.weights[i] == 0.0)
        if s.nearest <= 1.5 * cfg.min_distance:  # inside: a sample within the sampling radius
            inside.append(s.error)
    assert len(inside) >= 3
    assert max(inside) < 0.02, inside
    loo = leave_one_out(fn, ex, cfg)
    assert np.median(loo) < 0.03


def test_target_outside_is_projected_and_says_how_far(reaches) -> None:
    _, ex, fn = reaches
    sp = build_space(fn, ex, ParameterizeParams(samples=300))
    far = sp.params.mean(axis=0) + np.array([0.0, 3.0, 0.0])
    s = sp.synthesize(far)
    assert s.outside
    assert satisfies_eq1(s.weights, sp.cfg.extrapolation)
    assert s.error == pytest.approx(np.linalg.norm(s.achieved - far))
    assert s.error > 2.0  # the wrist cannot reach 3 m above the region: it stays in it
    assert s.achieved[1] <= sp.params[:, 1].max() + 0.05
    inside = sp.synthesize(sp.params[ex.n + 3] + 0.002)
    assert not inside.outside


def test_a_duplicated_example_is_redundant(reaches) -> None:
    _, ex, fn = reaches
    dup = ex.subset([*range(ex.n), 2])
    assert 2 in redundant_examples(fn, dup, 0.00635) or ex.n in redundant_examples(fn, dup, 0.00635)


def test_too_few_examples_and_a_bad_target_fail_clearly(reaches) -> None:
    _, ex, fn = reaches
    with pytest.raises(ValueError, match="needs at least d \\+ 1 = 4"):
        build_space(fn, ex.subset([0, 1, 2]))
    sp = build_space(fn, ex, ParameterizeParams(samples=50))
    with pytest.raises(ValueError, match="target has 2 values"):
        sp.synthesize(np.zeros(2))


@pytest.mark.parametrize("spec, message", [
    ("position:RightHand", "expected position:JOINT@SECONDS"),
    ("position:RightHand@soon", "not a time"),
    ("final_root:Hips", "takes no joint"),
    ("wiggle", "unknown kind 'wiggle'"),
    ("custom:no_such_module_xyz.fn", "cannot import"),
])
def test_bad_param_specs_fail_with_one_line(spec: str, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        parse_param(spec)


def test_parameter_functions_check_joint_and_time(reaches) -> None:
    _, ex, _ = reaches
    from motionweb.tasks.parameterize import check_param

    with pytest.raises(ValueError, match="unknown joint 'Nose'"):
        check_param(parse_param("position:Nose@0.5"), ex)
    with pytest.raises(ValueError, match="outside the query"):
        check_param(parse_param("position:Head@99"), ex)
    custom = parse_param("custom:fixtures.lowest_root")
    check_param(custom, ex)
    assert custom.dim == 1
    np.testing.assert_allclose(custom(ex, np.eye(ex.n)), parse_param("lowest_hip")(ex, np.eye(ex.n)))


def test_kick_ankle_and_final_root_parameters_match_the_truth() -> None:
    motions, truths, ex = space_of("kick", "kick", range(8), "side")
    k0 = action_keys(truths[0], "kick")
    foot = truths[0]["targets"][0]["effector"]
    p = example_params(parse_param(f"position:{foot}@{k0[2]:.6f}"), ex)
    np.testing.assert_allclose(p, [t["targets"][0]["position"] for t in truths], atol=0.002)
    root = example_params(FinalRoot(), ex)
    assert np.abs(root).max() < 0.1  # a kick ends where it started
