"""Guided time warping (HDP07 §3, design §7).

Every fast kernel is checked against a slow, obviously correct reference written here: the local
scores against a per-triple loop with a full sort, the constrained and unconstrained shortest
paths against enumeration of all subsequences on tiny inputs.
"""

from __future__ import annotations

import os
import re
from dataclasses import replace

import numpy as np
import pytest
from motionweb.store.kinematics import quat_from_euler, sample_motion
from motionweb.store.motion import Motion, Skeleton
from motionweb.tasks.guided_warp import (
    WarpParams,
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
    pose_error,
    reduce_to_compression,
    reference_features,
    smooth_warp,
    triple_blocks,
    triple_features,
    triple_index,
)
from naive import brute_force, slow_scores

ROT = ("Zrotation", "Xrotation", "Yrotation")
POS = ("Xposition", "Yposition", "Zposition")


# ------------------------------------------------------------------------------------ test data
def small_skeleton(extra_joint: bool = False) -> Skeleton:
    names = ["hips", "spine", "head", "lhip", "lknee", "lfoot", "rhip", "rknee", "rfoot", "lsh", "lelb",
             "rsh", "relb"]
    parents = [-1, 0, 1, 0, 3, 4, 0, 6, 7, 1, 9, 1, 11]
    offsets = [[0, 0, 0], [0, 20, 0], [0, 25, 0], [9, 0, 0], [0, -42, 0], [0, -40, 0], [-9, 0, 0],
               [0, -42, 0], [0, -40, 0], [15, 20, 0], [0, -28, 0], [-15, 20, 0], [0, -28, 0]]
    if extra_joint:
        names.append("tail")
        parents.append(0)
        offsets.append([0, 0, -10])
    return Skeleton(tuple(names), np.array(parents), np.array(offsets, float),
                    tuple([POS + ROT] + [ROT] * (len(names) - 1)), {2: np.array([0, 10.0, 0])})


def walk_then_jump(fps: float = 60.0, walk_s: float = 3.0, flight_s: float = 0.5) -> tuple[Motion, tuple[int, int]]:
    """A walk (1 Hz gait, forward 1.2 m/s), crouch, ballistic flight, landing, stand (cm).

    Returns the motion and the first and last frames of the flight.
    """
    g = 981.0
    crouch_s, land_s, stand_s = 0.35, 0.35, 0.5
    n = round((walk_s + crouch_s + flight_s + land_s + stand_s) * fps) + 1
    t = np.arange(n) / fps
    eul = np.zeros((n, 13, 3))
    root = np.zeros((n, 3))
    root[:, 1] = 82.0
    w = t < walk_s
    ph = 2 * np.pi * t
    eul[w, 3, 1], eul[w, 6, 1] = 30 * np.sin(ph[w]), -30 * np.sin(ph[w])
    eul[w, 4, 1] = 35 * np.maximum(0, np.sin(ph[w] + 1.2))
    eul[w, 7, 1] = 35 * np.maximum(0, -np.sin(ph[w] + 1.2))
    eul[w, 9, 1], eul[w, 11, 1] = -20 * np.sin(ph[w]), 20 * np.sin(ph[w])
    root[w, 1] += 2.5 * np.cos(2 * ph[w])
    root[:, 2] = np.where(w, 120 * t, 120 * walk_s + 60 * (t - walk_s))

    def bend(mask: np.ndarray, u: np.ndarray, arms: np.ndarray) -> None:
        b = np.sin(np.pi * u)
        eul[mask, 3, 1] = eul[mask, 6, 1] = -40 * b
        eul[mask, 4, 1] = eul[mask, 7, 1] = 70 * b
        eul[mask, 9, 1] = eul[mask, 11, 1] = arms
        root[mask, 1] -= 20 * b

    t1 = walk_s + crouch_s
    c = (t >= walk_s) & (t < t1)
    bend(c, (t[c] - walk_s) / crouch_s, 60 * (t[c] - walk_s) / crouch_s)
    t2 = t1 + flight_s
    f = (t >= t1) & (t < t2)
    tf = t[f] - t1
    root[f, 1] = 82.0 + g * flight_s / 2 * tf - 0.5 * g * tf ** 2
    tuck = np.sin(np.pi * tf / flight_s)
    eul[f, 3, 1] = eul[f, 6, 1] = -50 * tuck
    eul[f, 4, 1] = eul[f, 7, 1] = 80 * tuck
    eul[f, 9, 1] = eul[f, 11, 1] = 60 + 90 * tuck
    t3 = t2 + land_s
    land = (t >= t2) & (t < t3)
    bend(land, (t[land] - t2) / land_s, 60 * (1 - (t[land] - t2) / land_s))
    motion = Motion(small_skeleton(), fps, root, quat_from_euler(eul, "ZXY"), name="walkjump", unit="cm")
    fl = np.flatnonzero(f)
    return motion, (int(fl[0]), int(fl[-1]))


@pytest.fixture(scope="module")
def walkjump() -> tuple[Motion, tuple[int, int]]:
    return walk_then_jump()


def check_path(path: np.ndarray, n: int, m: int | None, skip: int, keys=()) -> None:
    assert path[0] == 0 and path[-1] == n - 1
    if m is not None:
        assert len(path) == m
    steps = np.diff(path)
    assert steps.min() >= 1 and steps.max() <= skip
    for f, o in keys:
        assert path[o] == f


# ------------------------------------------------------------------------------- slow references
# ---------------------------------------------------------------------------------------- kernels
def test_local_scores_match_slow_loop(walkjump):
    motion, _ = walkjump
    track = motion_track(motion.slice(170, 184), 3)
    ref = motion_track(motion.slice(195, 215), 3)
    spec = feature_spec(ref, (1.0, 2.0, 0.5))
    fast = local_scores(track, reference_features(ref, spec), 3, spec, neighbours=3, batch=7)
    slow = slow_scores(track, ref, 3, 3, spec)
    assert np.array_equal(np.isinf(fast), np.isinf(slow))
    np.testing.assert_allclose(fast[np.isfinite(fast)], slow[np.isfinite(slow)], rtol=1e-7, atol=1e-9)


@pytest.mark.parametrize("root_motion", [True, False])
def test_triple_kernel_matches_numpy_blocks(walkjump, root_motion):
    motion, _ = walkjump
    track = motion_track(motion.slice(100, 160), 3)
    spec = feature_spec(track, (1.0, 2.0, 0.5), root_motion=root_motion)
    j, a, b = triple_index(len(track), 4)
    slow = spec.combine(triple_blocks(track.take(j - a), track.take(j), track.take(j + b), root_motion))
    np.testing.assert_allclose(triple_features(track, j, a, b, spec), slow, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("n,m,s,seed", [(9, 5, 3, 0), (10, 4, 4, 1), (8, 8, 2, 2), (11, 6, 3, 3), (7, 2, 6, 4)])
def test_fixed_length_dp_matches_brute_force(n, m, s, seed):
    table = np.random.default_rng(seed).random((n, s, s))
    path, cost = fixed_length_path(table, m)
    best, arg = brute_force(table, m)
    assert cost == pytest.approx(best)
    assert tuple(path) == arg
    assert path_cost(table, path) == pytest.approx(cost)


@pytest.mark.parametrize("seed", range(4))
def test_keytimes_dp_matches_brute_force(seed):
    rng = np.random.default_rng(10 + seed)
    n, m, s = 12, 7, 3
    table = rng.random((n, s, s))
    keys = [(0, 0), (int(rng.integers(3, 6)), 3), (n - 1, m - 1)]
    lo, hi = feasible_windows(n, m, s, keys)
    path, cost = fixed_length_path(table, m, lo, hi)
    best, arg = brute_force(table, m, keys[1:2])
    assert cost == pytest.approx(best) and tuple(path) == arg
    check_path(path, n, m, s, keys)


@pytest.mark.parametrize("n,s,seed", [(9, 3, 0), (11, 4, 1), (6, 2, 2)])
def test_unconstrained_dag_matches_brute_force(n, s, seed):
    table = np.random.default_rng(seed).random((n, s, s)) + 0.01
    path, cost = dag_path(table)
    best, arg = brute_force(table, None)
    assert cost == pytest.approx(best) and tuple(path) == arg
    check_path(path, n, None, s)


def test_smooth_warp_keeps_anchors_and_monotonicity():
    rng = np.random.default_rng(5)
    raw = np.cumsum(rng.integers(1, 6, 60)).astype(float)
    raw -= raw[0]
    sm = smooth_warp(raw, 7, anchors=[20, 41])
    assert np.all(np.diff(sm) > 0)
    for a in (0, 20, 41, 59):
        assert sm[a] == raw[a]
    lin = np.linspace(0, 30, 25)
    np.testing.assert_allclose(smooth_warp(lin, 5), lin, atol=1e-12)


# ------------------------------------------------------------------------------------ warps
def test_identity_when_lengths_match(walkjump):
    motion, _ = walkjump
    r = guided_warp(motion, n_out=motion.n_frames)
    assert np.array_equal(r.frames, np.arange(motion.n_frames))
    np.testing.assert_allclose(r.times, np.arange(motion.n_frames), atol=1e-12)
    assert pose_error(r.motion, motion) < 1e-9


@pytest.mark.parametrize("frac,keys,fast", [(0.7, (), False), (0.5, ((100.0, 50.0), (200.0, 110.0)), False),
                                              (0.6, ((150.0, 80.0),), True), (0.3, (), True)])
def test_results_are_complete_monotone_and_hit_keytimes(walkjump, frac, keys, fast):
    motion, _ = walkjump
    n = motion.n_frames
    m = round(frac * (n - 1)) + 1
    r = guided_warp(motion, n_out=m, keytimes=keys, fast=fast)
    check_path(r.frames, n, m, 8, [(int(i), int(o)) for i, o in keys])
    assert r.motion.n_frames == m and r.motion.fps == motion.fps
    assert np.all(np.diff(r.times) > 0) and r.times[0] == 0 and r.times[-1] == n - 1
    for i, o in keys:
        assert r.times[int(o)] == i and r.raw_times[int(o)] == i


def test_heuristic_close_to_optimal(walkjump):
    motion, _ = walkjump
    m = round(0.6 * (motion.n_frames - 1)) + 1
    full = guided_warp(motion, n_out=m, resample_motion=False)
    fast = guided_warp(motion, n_out=m, fast=True, resample_motion=False)
    assert fast.heuristic
    assert full.cost <= fast.cost <= 1.05 * full.cost + 1e-9


def test_known_nonlinear_warp_is_undone(walkjump):
    motion, _ = walkjump
    original = motion.slice(0, 180)  # the walk
    n = original.n_frames
    # a slowed-down copy with a speed varying between 0.45x and 0.95x
    speed = 0.7 + 0.25 * np.sin(np.linspace(0, 3 * np.pi, 400))
    src = np.concatenate([[0.0], np.cumsum(speed)])
    src = src[src <= n - 1]
    src = np.append(src, n - 1.0)
    warped = replace(sample_motion(original, src), name="slowed")
    r = guided_warp(warped, reference=original, n_out=n)
    lin = linear_warp(warped, n)
    err, err_lin = pose_error(r.motion, original), pose_error(lin.motion, original)
    # the recovered warp maps output frames back to the original's frames
    drift = np.abs(np.interp(r.times, np.arange(len(src)), src) - np.arange(n))
    drift_lin = np.abs(np.interp(lin.times, np.arange(len(src)), src) - np.arange(n))
    assert drift.mean() < 3.0 and drift.mean() < 0.3 * drift_lin.mean(), (drift.mean(), drift_lin.mean())
    assert err < 0.25 * err_lin, (err, err_lin)


def test_walk_then_jump_keeps_flight_at_natural_speed(walkjump):
    motion, (f0, f1) = walkjump
    n = motion.n_frames
    m = round(0.6 * (n - 1)) + 1
    r = guided_warp(motion, n_out=m)
    lin = linear_warp(motion, m)
    walk_end = f0 - 40
    assert playback_speed(r.times, f0, f1) == pytest.approx(1.0, abs=0.1)
    assert playback_speed(r.times, 0, walk_end) >= 1.4
    assert playback_speed(lin.times, f0, f1) == pytest.approx((n - 1) / (m - 1))  # linear speeds the jump up
    assert playback_speed(lin.times, f0, f1) > 1.6


def test_expansion_by_upsampling(walkjump):
    motion, (f0, f1) = walkjump
    n = motion.n_frames
    m = round(1.5 * (n - 1)) + 1
    r = guided_warp(motion, n_out=m, keytimes=[(f0, 290.0)])
    assert r.upsample >= 2
    check_path(r.frames, r.upsample * (n - 1) + 1, m, 8, [(r.upsample * f0, 290)])
    assert r.motion.n_frames == m and np.all(np.diff(r.times) > 0)
    assert r.times[0] == 0 and r.times[-1] == n - 1 and r.times[290] == f0
    steps = np.diff(r.raw_times)
    assert steps.min() >= 1.0 / r.upsample - 1e-12 and steps.max() <= 8.0 / r.upsample + 1e-12
    # the flight keeps its own timing while the rest slows down
    assert playback_speed(r.times, f0, f1) == pytest.approx(1.0, abs=0.15)
    assert playback_speed(r.times, 0, f0 - 40) < 0.8


def test_backward_warp_reverses(walkjump):
    motion, _ = walkjump
    n = motion.n_frames
    r = guided_warp(motion, n_out=200, keytimes=[(150.0, 90.0)], backward=True)
    assert r.backward and r.raw_times[0] == n - 1 and r.raw_times[-1] == 0
    assert np.all(np.diff(r.times) < 0) and r.times[90] == 150.0


def test_unconstrained_warp(walkjump):
    motion, _ = walkjump
    r = guided_warp(motion, n_out=None, params=WarpParams(skip=4))
    check_path(r.frames, motion.n_frames, None, 4)
    assert r.motion.n_frames == len(r.frames)


# ------------------------------------------------------------------------------------ bad input
def test_bad_inputs_raise(walkjump):
    motion, _ = walkjump
    n = motion.n_frames
    other = Motion(small_skeleton(extra_joint=True), motion.fps, motion.root_positions,
                   np.concatenate([motion.rotations, motion.rotations[:, :1]], axis=1))
    with pytest.raises(ValueError, match="different skeletons"):
        guided_warp(motion, other, n_out=200)
    with pytest.raises(ValueError, match="below n/s"):
        guided_warp(motion, n_out=(n - 1) // 8)
    with pytest.raises(ValueError, match="at least 3 frames"):
        guided_warp(motion, motion.slice(0, 2), n_out=200)
    with pytest.raises(ValueError, match="strictly increasing"):
        reduce_to_compression(n, 200, [(100.0, 50.0), (80.0, 120.0)], 8)
    with pytest.raises(ValueError, match="strictly increasing output"):
        reduce_to_compression(n, 200, [(100.0, 50.0), (120.0, 50.0)], 8)
    with pytest.raises(ValueError, match="outside the input"):
        reduce_to_compression(n, 200, [(n + 5.0, 50.0)], 8)
    with pytest.raises(ValueError, match="outside the output"):
        reduce_to_compression(n, 200, [(100.0, 250.0)], 8)
    with pytest.raises(ValueError, match="need an output length"):
        reduce_to_compression(n, None, [(100.0, 50.0)], 8)
    with pytest.raises(ValueError, match="range of speeds"):
        reduce_to_compression(n, 200, [(270.0, 10.0)], 8)


# ------------------------------------------------------------------------------------ flow + CLI
def test_cli_warp_end_to_end(walkjump, tmp_path):
    """One real flow run through the CLI: BVH and plot written; then errors without a flow run."""
    for key, value in {"PREFECT_SERVER_ANALYTICS_ENABLED": "false", "PREFECT_LOGGING_LEVEL": "WARNING",
                       "PREFECT_LOGGING_TO_API_WHEN_MISSING_FLOW": "ignore",
                       "PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS": "90"}.items():
        os.environ.setdefault(key, value)
    from motionweb.flows.commands.cli import app
    from motionweb.store.bvh import read_bvh, write_bvh
    from typer.testing import CliRunner

    motion, (f0, _) = walkjump
    src = tmp_path / "walkjump.bvh"
    write_bvh(motion, src)
    src.with_suffix(".json").write_text('{"unit": "cm"}')  # the flight phase needs metres
    out, plot = tmp_path / "out.bvh", tmp_path / "warp.png"
    runner = CliRunner()
    res = runner.invoke(app, ["warp", str(src), "--duration", "2.8", "--keytime", f"{f0 / 60:.4f}:1.6",
                              "--out", str(out), "--plot", str(plot)])
    assert res.exit_code == 0, res.output
    warped = read_bvh(out)
    assert warped.n_frames == 169 and warped.skeleton.channels == motion.skeleton.channels
    assert warped.unit == motion.unit or warped.unit is None
    assert plot.stat().st_size > 1000
    flight = re.search(r"flight (\d+\.\d+) s -> (\d+\.\d+) s \(x(\d+\.\d+)\)", res.output)
    assert flight, res.output  # the summary says what the warp did to the flight
    assert 0.45 < float(flight[1]) < 0.65 and float(flight[3]) == pytest.approx(float(flight[2]) / float(flight[1]), abs=0.01)

    res = runner.invoke(app, ["warp", str(src), "--frames", "20", "--out", str(out)])
    assert res.exit_code != 0 and "below n/s" in res.output and "Traceback" not in res.output
    res = runner.invoke(app, ["warp", str(src), "--frames", "200", "--keytime", "1.0:2.0", "--keytime",
                              "0.5:2.5", "--out", str(out)])
    assert res.exit_code != 0 and "strictly increasing" in res.output
    res = runner.invoke(app, ["warp", str(src), "--out", str(out)])
    assert res.exit_code != 0 and "--duration" in res.output
    res = runner.invoke(app, ["warp", str(src), "--frames", "200", "--keytime", "oops", "--out", str(out)])
    assert res.exit_code != 0 and "IN_S:OUT_S" in res.output
