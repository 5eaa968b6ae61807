"""Parameterized motion: parameter functions, sampling, k-nearest interpolation (KG04 §4.2–4.4).

A parameter function f maps blend weights to a parameter vector p (KG04 §4): it is evaluated on
the blend of the registered examples (``tasks/blend.py``), vectorised over many weight vectors
(S, N) -> (S, d), in the blend's start-heading frame (origin: the root at the first sample on the
ground, +Z the start heading). Built-ins (:func:`parse_param`, spec ``KIND[:JOINT[@SECONDS]]``):

* ``position:JOINT@SECONDS`` — the joint's position (3) at a time of the query (seconds from the
  query's start), carried to every example by the registration (KG04 §4.1, last paragraph);
* ``final_root`` — the final root position on the ground (x, z) (2);
* ``lowest_hip`` — the lowest root height (1);
* ``max_speed:JOINT`` — the joint's highest speed (m/s) over the blend (1);
* ``custom:package.module.function`` — any callable ``f(examples, weights) -> (S, d)``. A config
  or command naming one imports and runs that code: only name code you trust.

Sampling (§4.2, :func:`sample_space`): the examples' parameters' bounding box grown 20% about its
centre; random points in it; for each the d + 1 nearest examples get random near-convex weights
(Eq. 1: −δ ≤ w_i ≤ 1 + δ, Σ w_i = 1, assigned in random order from the interval that keeps the
running sum valid, the last one 1 − S); the blend's parameters are a new sample unless one closer
than ``min_distance`` (the paper's half inch, 1.27 cm) exists. Interpolation (§4.3,
:meth:`MotionSpace.weights_for`): the k = 12 nearest samples, α_i = 1/D(p, p_i) − 1/D(p, p_k)
normalised (an exact hit takes that sample's weights); the result stays inside the samples'
convex hull of weights, so a target outside the accessible region is projected onto it and the
answer reports how far it landed from the target. Redundant examples (§4.4,
:func:`redundant_examples`): an example whose parameters the interpolation of the remaining
examples reproduces within a tolerance is dropped.

Cost: sampling n points is O(n·(N·d + (d+1)·C_f)) with C_f the cost of f on one blend (a
position: compiled FK of two samples along the joint's root path only; the root: O(U)), and the
duplicate check O(n²·d) in blocks; interpolation O(n·d) brute force or O(log n) with the k-d tree, independent of N.
"""

from __future__ import annotations

import importlib
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from motionweb.store.kinematics import forward_kinematics_of
from motionweb.tasks.blend import Examples, blend_durations, blend_path, blend_poses, check_weights, posed
from motionweb.tasks.params.parameterize import ParameterizeParams
from scipy.spatial import cKDTree


# ----------------------------------------------------------------------------- parameter functions
class ParamFunction:
    """f(examples, weights (S, N)) -> (S, d); ``spec`` is its text form, ``dim`` its d."""

    spec: str = ""
    dim: int = 0

    def __call__(self, ex: Examples, weights: np.ndarray) -> np.ndarray:
        raise NotImplementedError


def start_frame_positions(pos: np.ndarray) -> np.ndarray:
    """Blend positions are already in the start-heading frame, but the root starts above the origin:
    take the start's ground point away (only x and z)."""
    return pos - pos[:, :1] * np.array([1.0, 0.0, 1.0])


@dataclass
class JointPosition(ParamFunction):
    """A joint's position (x, y, z) at query time ``seconds`` (KG04 §4.1: the query frame mapped
    to the sample u0 of the registration), linearly interpolated between samples."""

    joint: str
    seconds: float
    dim: int = 3

    @property
    def spec(self) -> str:  # type: ignore[override]
        return f"position:{self.joint}@{self.seconds:g}"

    def __call__(self, ex: Examples, weights: np.ndarray) -> np.ndarray:
        w = check_weights(weights, ex.n)
        j = joint_index(ex, self.joint)
        u = self.seconds * ex.rate
        if not 0.0 <= u <= ex.n_samples - 1 + 1e-9:
            raise ValueError(f"time {self.seconds:g} s is outside the query (0 .. {(ex.n_samples - 1) / ex.rate:g} s)")
        u0 = min(int(math.floor(u)), ex.n_samples - 2)
        t = u - u0
        pos, phi = blend_path(ex, w, upto=u0 + 1)
        local = blend_poses(ex, w, slice(u0, u0 + 2))  # (S, 2, J, 4)
        s = len(w)
        m = posed(ex, pos[:, u0:u0 + 2].reshape(-1, 3), phi[:, u0:u0 + 2].reshape(-1),
                  local.reshape(2 * s, *local.shape[2:]), ex.rate)
        gpos, _ = forward_kinematics_of(m, [j])
        p = gpos[:, j].reshape(s, 2, 3)
        return (1.0 - t) * p[:, 0] + t * p[:, 1]


@dataclass
class FinalRoot(ParamFunction):
    """The final root position on the ground (x, z) in the start-heading frame."""

    dim: int = 2
    spec: str = "final_root"

    def __call__(self, ex: Examples, weights: np.ndarray) -> np.ndarray:
        pos, _ = blend_path(ex, weights)
        return pos[:, -1][:, [0, 2]]


@dataclass
class LowestHip(ParamFunction):
    """The lowest root height (m) over the blend."""

    dim: int = 1
    spec: str = "lowest_hip"

    def __call__(self, ex: Examples, weights: np.ndarray) -> np.ndarray:
        pos, _ = blend_path(ex, weights)
        return pos[..., 1].min(axis=1)[:, None]


@dataclass
class MaxSpeed(ParamFunction):
    """A joint's highest speed (m/s) over the blend, on the blend's own timing."""

    joint: str
    dim: int = 1

    @property
    def spec(self) -> str:  # type: ignore[override]
        return f"max_speed:{self.joint}"

    def __call__(self, ex: Examples, weights: np.ndarray) -> np.ndarray:
        w = check_weights(weights, ex.n)
        j = joint_index(ex, self.joint)
        pos, phi = blend_path(ex, w)
        local = blend_poses(ex, w)
        s, u = pos.shape[:2]
        m = posed(ex, pos.reshape(-1, 3), phi.reshape(-1), local.reshape(s * u, *local.shape[2:]), ex.rate)
        gpos, _ = forward_kinematics_of(m, [j])
        p = gpos[:, j].reshape(s, u, 3)
        dt = blend_durations(ex, w)
        return (np.linalg.norm(np.diff(p, axis=1), axis=-1) / dt).max(axis=1)[:, None]


@dataclass
class CustomParam(ParamFunction):
    """A parameter function imported by path (``package.module.function``): code named in a
    config is code and runs with the caller's rights."""

    path: str
    dim: int = 0
    fn: Callable[[Examples, np.ndarray], np.ndarray] | None = field(default=None, repr=False)

    @property
    def spec(self) -> str:  # type: ignore[override]
        return f"custom:{self.path}"

    def __call__(self, ex: Examples, weights: np.ndarray) -> np.ndarray:
        w = check_weights(weights, ex.n)
        try:
            out = np.asarray(self.fn(ex, w), np.float64)  # type: ignore[misc]
            return out.reshape(len(w), -1)
        except Exception as exc:  # noqa: BLE001 - any failure of imported code becomes one clear line
            raise ValueError(f"parameter function {self.spec} failed: {type(exc).__name__}: {exc}") from None


def joint_index(ex: Examples, name: str) -> int:
    if name not in ex.skeleton.names:
        raise ValueError(f"unknown joint {name!r}; joints: {', '.join(ex.skeleton.names)}")
    return ex.skeleton.index(name)


KINDS = ("position", "final_root", "lowest_hip", "max_speed", "custom")


def parse_param(spec: str) -> ParamFunction:
    """A parameter function from ``KIND[:JOINT[@SECONDS]]`` (see the module docstring)."""
    kind, _, rest = spec.partition(":")
    if kind == "position":
        joint, at, sec = rest.partition("@")
        if not joint or not at:
            raise ValueError(f"--param {spec!r}: expected position:JOINT@SECONDS, e.g. position:RightHand@1.2")
        try:
            return JointPosition(joint, float(sec))
        except ValueError:
            raise ValueError(f"--param {spec!r}: {sec!r} is not a time in seconds") from None
    if kind in ("final_root", "lowest_hip"):
        if rest:
            raise ValueError(f"--param {spec!r}: {kind} takes no joint")
        return FinalRoot() if kind == "final_root" else LowestHip()
    if kind == "max_speed":
        if not rest or "@" in rest:
            raise ValueError(f"--param {spec!r}: expected max_speed:JOINT")
        return MaxSpeed(rest)
    if kind == "custom":
        mod, _, name = rest.rpartition(".")
        if not mod:
            raise ValueError(f"--param {spec!r}: expected custom:package.module.function")
        try:
            fn = getattr(importlib.import_module(mod), name)
        except (ImportError, AttributeError) as exc:
            raise ValueError(f"--param {spec!r}: cannot import {rest!r} ({exc})") from None
        return CustomParam(rest, fn=fn)
    raise ValueError(f"--param {spec!r}: unknown kind {kind!r}; expected one of {', '.join(KINDS)}")


def check_param(fn: ParamFunction, ex: Examples) -> None:
    """Evaluate ``fn`` once on the first example so a bad joint or time fails before sampling."""
    w = np.zeros((1, ex.n))
    w[0, 0] = 1.0
    p = fn(ex, w)
    if fn.dim == 0:
        fn.dim = p.shape[1]
    if p.shape != (1, fn.dim) or not np.all(np.isfinite(p)):
        raise ValueError(f"parameter function {fn.spec} returned {p.shape} values (expected (1, {fn.dim}), finite)")


# ----------------------------------------------------------------------------------- sampling
def near_convex_weights(n_points: int, n_active: int, delta: float, rng: np.random.Generator) -> np.ndarray:
    """(n_points, n_active) random weights satisfying Eq. (1) of KG04 §4.2, assigned in random
    order: each from [max(−δ, −δ − S), min(1 + δ, 1 + δ − S)] given the running sum S, the last
    one 1 − S, so every weight and every partial sum stays in [−δ, 1 + δ]."""
    w = np.empty((n_points, n_active))
    order = np.argsort(rng.random((n_points, n_active)), axis=1)
    s = np.zeros(n_points)
    rows = np.arange(n_points)
    for k in range(n_active - 1):
        lo = np.maximum(-delta, -delta - s)
        hi = np.minimum(1.0 + delta, 1.0 + delta - s)
        v = lo + (hi - lo) * rng.random(n_points)
        w[rows, order[:, k]] = v
        s += v
    w[rows, order[:, -1]] = 1.0 - s
    return w


def satisfies_eq1(weights: np.ndarray, delta: float, tol: float = 1e-9) -> bool:
    """Every row within [−δ, 1 + δ] and summing to 1 (KG04 Eq. 1)."""
    w = np.atleast_2d(weights)
    return bool(np.all(w >= -delta - tol) and np.all(w <= 1.0 + delta + tol)
                and np.all(np.abs(w.sum(axis=1) - 1.0) < 1e-6))


def example_params(fn: ParamFunction, ex: Examples) -> np.ndarray:
    """(N, d) parameters of every example (one-hot blends)."""
    return fn(ex, np.eye(ex.n))


def sample_space(fn: ParamFunction, ex: Examples, cfg: ParameterizeParams,
                 active: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """KG04 §4.2 sampling over the examples ``active`` (all by default; the others get weight 0).

    Returns (params (M, d), indices (M, d + 1) of the examples blended, weights (M, d + 1)); the
    first rows are the examples themselves (one-hot), then the accepted random samples, none
    closer than ``min_distance`` to an earlier row. ValueError with fewer than d + 1 examples.
    """
    act = np.arange(ex.n) if active is None else np.asarray(active)
    p_ex = example_params(fn, ex)[act]
    d = p_ex.shape[1]
    if len(act) < d + 1:
        raise ValueError(f"{len(act)} examples for a {d}-D parameter: sampling needs at least d + 1 = {d + 1}")
    rng = np.random.default_rng(cfg.seed)
    lo, hi = p_ex.min(axis=0), p_ex.max(axis=0)
    centre, half = 0.5 * (lo + hi), 0.5 * (hi - lo) * (1.0 + cfg.grow)
    pts = centre + half * (2.0 * rng.random((cfg.samples, d)) - 1.0)
    _, near = cKDTree(p_ex).query(pts, k=d + 1)
    near = np.asarray(near).reshape(cfg.samples, d + 1)
    wloc = near_convex_weights(cfg.samples, d + 1, cfg.extrapolation, rng)
    full = np.zeros((cfg.samples, ex.n))
    np.put_along_axis(full, act[near], wloc, axis=1)
    params = np.empty((cfg.samples, d))
    for a in range(0, cfg.samples, 256):
        params[a:a + 256] = fn(ex, full[a:a + 256])
    keep = dedupe(np.concatenate([p_ex, params]), len(p_ex), cfg.min_distance)
    one_hot = np.zeros((len(act), d + 1))
    one_hot[:, 0] = 1.0
    idx = np.concatenate([np.repeat(act[:, None], d + 1, axis=1), act[near]])[keep]
    wts = np.concatenate([one_hot, wloc])[keep]
    return np.concatenate([p_ex, params])[keep], idx, wts


def dedupe(points: np.ndarray, n_fixed: int, radius: float) -> np.ndarray:
    """Indices of the rows kept: the first ``n_fixed`` always, every later row unless a kept row
    lies closer than ``radius`` (KG04 §4.2). O(M²·d) for M rows, one vectorised check per row."""
    pts = np.asarray(points, np.float64)
    kept = np.empty(len(pts), np.int64)
    kept[:n_fixed] = np.arange(n_fixed)
    nk, r2 = n_fixed, radius * radius
    for i in range(n_fixed, len(pts)):
        if nk == 0 or np.min(((pts[kept[:nk]] - pts[i]) ** 2).sum(axis=1)) >= r2:
            kept[nk] = i
            nk += 1
    return kept[:nk]


# ----------------------------------------------------------------------------------- the space
@dataclass
class Synthesis:
    """Weights (N,) for a target, the parameters f gives for them, how far those are from the
    target (m), the distance from the target to the nearest sample, and whether the target lay
    outside the sampled region (``outside``: farther from every sample than the region's spacing
    allows) and was projected onto it."""

    weights: np.ndarray
    target: np.ndarray
    achieved: np.ndarray
    error: float
    nearest: float
    outside: bool


@dataclass
class MotionSpace:
    """A parameterized motion (KG04 §4): examples, their parameters, the samples (parameters
    (M, d), sparse weights: example indices and weights (M, d + 1)) and the parameter function.
    ``spacing`` is the median distance from a sample to its nearest other sample."""

    examples: Examples
    fn: ParamFunction
    example_params: np.ndarray
    params: np.ndarray
    indices: np.ndarray
    weights: np.ndarray
    cfg: ParameterizeParams
    tree: cKDTree = field(init=False, repr=False)
    spacing: float = field(init=False)

    def __post_init__(self) -> None:
        self.tree = cKDTree(self.params)
        if len(self.params) > 1:
            dd, _ = self.tree.query(self.params, k=2)
            self.spacing = float(np.median(dd[:, 1]))
        else:
            self.spacing = 0.0

    @property
    def dim(self) -> int:
        return self.params.shape[1]

    def dense_weights(self, rows: np.ndarray, alpha: np.ndarray) -> np.ndarray:
        """(N,) Σ α_r w_r over sample rows (KG04 Eq. 2)."""
        w = np.zeros(self.examples.n)
        np.add.at(w, self.indices[rows].ravel(), (alpha[:, None] * self.weights[rows]).ravel())
        return w

    def weights_for(self, target: np.ndarray) -> tuple[np.ndarray, float]:
        """KG04 §4.3: blend weights (N,) for a target parameter (d,), and the nearest sample's
        distance. α_i = 1/D_i − 1/D_k over the k nearest samples, normalised; exact hit: that
        sample. O(log M + k·d)."""
        p = np.asarray(target, np.float64).reshape(-1)
        if p.shape != (self.dim,):
            raise ValueError(f"target has {p.size} values; the space's parameter ({self.fn.spec}) has {self.dim}")
        k = min(self.cfg.k, len(self.params))
        dist, rows = self.tree.query(p, k=k)
        dist, rows = np.atleast_1d(dist), np.atleast_1d(rows)
        if dist[0] < 1e-12:
            return self.dense_weights(rows[:1], np.ones(1)), float(dist[0])
        alpha = 1.0 / dist - 1.0 / dist[-1]
        alpha = np.ones(k) if alpha.sum() <= 0 else alpha
        return self.dense_weights(rows, alpha / alpha.sum()), float(dist[0])

    def synthesize(self, target: np.ndarray) -> Synthesis:
        """Weights for ``target`` and what they achieve (f evaluated on their blend). With
        ``cfg.refine`` > 0 the looked-up point is moved by the remaining error and looked up
        again, keeping the best weights: still a k-NN average of samples' weights, so Eq. (1)
        holds, but the inverse-distance bias of §4.3 shrinks (one f evaluation per round)."""
        t = np.asarray(target, np.float64).reshape(-1)
        w, nearest = self.weights_for(t)
        got = self.fn(self.examples, w[None])[0]
        best = (float(np.linalg.norm(got - t)), w, got)
        look = t
        for _ in range(self.cfg.refine):
            look = look + (t - got)
            w, _ = self.weights_for(look)
            got = self.fn(self.examples, w[None])[0]
            err = float(np.linalg.norm(got - t))
            if err < best[0]:
                best = (err, w, got)
        return Synthesis(best[1], t, best[2], best[0], nearest,
                         bool(nearest > 2.0 * max(self.spacing, self.cfg.min_distance)))


def build_space(fn: ParamFunction, ex: Examples, cfg: ParameterizeParams | None = None,
                active: np.ndarray | None = None) -> MotionSpace:
    """Sample a motion space over the examples ``active`` (all by default; KG04 §4.2)."""
    cfg = cfg or ParameterizeParams()
    check_param(fn, ex)
    params, idx, wts = sample_space(fn, ex, cfg, active)
    return MotionSpace(ex, fn, example_params(fn, ex), params, idx, wts, cfg)


def leave_one_out(fn: ParamFunction, ex: Examples, cfg: ParameterizeParams | None = None) -> np.ndarray:
    """(N,) for each example, the distance between its parameters and what a space built from
    the other examples achieves for them (m)."""
    cfg = cfg or ParameterizeParams()
    p = example_params(fn, ex)
    out = np.empty(ex.n)
    for i in range(ex.n):
        others = np.array([k for k in range(ex.n) if k != i])
        out[i] = build_space(fn, ex, cfg, others).synthesize(p[i]).error
    return out


def redundant_examples(fn: ParamFunction, ex: Examples, tol: float, k: int = 12) -> list[int]:
    """KG04 §4.4: examples, in order, whose parameters k-nearest interpolation of the remaining
    examples' parameters reproduces within ``tol`` (f evaluated on that blend); greedy."""
    p = example_params(fn, ex)
    keep = list(range(ex.n))
    dropped = []
    for i in range(ex.n):
        rest = [r for r in keep if r != i]
        if len(rest) < p.shape[1] + 1:
            break
        dist = np.linalg.norm(p[rest] - p[i], axis=1)
        order = np.argsort(dist)[:min(k, len(rest))]
        dd = dist[order]
        if dd[0] < 1e-12:
            alpha = (np.arange(len(order)) == 0).astype(np.float64)
        else:
            alpha = 1.0 / dd - 1.0 / dd[-1]
            alpha = np.ones(len(dd)) if alpha.sum() <= 0 else alpha
        w = np.zeros(ex.n)
        w[np.array(rest)[order]] = alpha / alpha.sum()
        if np.linalg.norm(fn(ex, w[None])[0] - p[i]) <= tol:
            keep.remove(i)
            dropped.append(i)
    return dropped
