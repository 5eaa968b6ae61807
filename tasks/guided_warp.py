"""Guided time warping (HDP07 = Hsu, da Silva & Popović 2007, §3; design §7).

A time warp of an input motion x_1..x_n is a subsequence y_1..y_m of its frame indices that starts
on the first frame, ends on the last one and never skips more than ``s`` frames (HDP07 §3.1). Its
quality is the sum over output triples of a local score f(y_{p-1}, y_p, y_{p+1}): the mean distance
of the triple's [pose, velocity, acceleration] feature to its k nearest reference features
(HDP07 §3.2, eqs. 1-2). The best subsequence of exactly m frames is a shortest path with m-2 edges
in the DAG whose vertices are frame pairs (i, j), 0 < j - i <= s, and whose edges (i,j)->(j,k) weigh
f(i,j,k) (HDP07 §3.3, eqs. 3-4): O(m n s²) time, O(n s²) scores. Without an output length it is a
plain DAG shortest path, O(n s²).

Every case is reduced to compression (HDP07 §3.1): an expansion upsamples the input by an integer
factor, a backward warp reverses it, several keytimes constrain the path to pass through given
(input frame, output frame) pairs. The result is postprocessed as in HDP07 §3.4: the discrete warp
is moving-averaged, the input is resampled at the warped times (slerp) and each output frame is
averaged over a window equal to the local compression.

Index conventions in this module are 0-based: the working input has frames 0..n-1, the output
0..m-1; the path layer p (0..m-2) is the vertex (y[p], y[p+1]).
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numba
import numpy as np
from motionweb.store.kinematics import (
    axis_index,
    forward_kinematics,
    heading_angle,
    quat_normalize,
    resample,
    sample_motion,
)
from motionweb.store.motion import Motion
from motionweb.store.params import Params
from scipy.ndimage import uniform_filter1d

Keytime = tuple[float, float]


class WarpParams(Params):
    """Guided time warping (design §7, HDP07 §3)."""

    skip: int = 8
    neighbours: int = 3
    filter_width: int = 5
    weights: tuple[float, float, float] = (1.0, 1.0, 1.0)
    heuristic_rate: int = 8
    #: half-width (working frames) of the full-rate band around the coarse solution (--fast)
    band: int = 48
    #: moving-average width of the warp, output frames (HDP07 §3.4)
    smooth_width: int = 5
    #: average each output frame over the local compression (HDP07 §3.4)
    adaptive_smoothing: bool = True
    #: divide pose/velocity/acceleration features by the reference's RMS spread of each
    normalize: bool = True
    #: velocities include the root's travel and turning (differences in the middle frame's torso frame)
    root_motion: bool = True


# ----------------------------------------------------------------------------------------------------------
# Results


@dataclass(frozen=True, eq=False)
class WarpResult:
    """A computed time warp.

    Attributes:
        frames: (m,) int, the discrete path in *working* input frames (after upsampling/reversal).
        raw_times: (m,) float, that path as source times in original input frames.
        times: (m,) float, the smoothed warp: output frame p shows the input at ``times[p]`` frames.
        cost: objective value (HDP07 eq. 1) of the discrete path (0 for the linear baseline).
        motion: the warped motion (input skeleton, fps and units), or None when not resampled.
        keytimes: the (input frame, output frame) pairs the warp interpolates, endpoints included.
        upsample: integer upsampling factor of the reduction to compression (1 = none).
        backward: whether the input was reversed.
        heuristic: whether the §3.3 band heuristic was used (and did not fall back to the full search).
        timings: seconds spent in 'features', 'objective', 'optimization', 'heuristic', 'postprocess'.
    """

    frames: np.ndarray
    raw_times: np.ndarray
    times: np.ndarray
    cost: float
    motion: Motion | None
    keytimes: list[Keytime]
    upsample: int = 1
    backward: bool = False
    heuristic: bool = False
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def n_out(self) -> int:
        return len(self.times)

    def speed(self) -> np.ndarray:
        """(m,) local playback speed: source frames per output frame (central differences)."""
        return np.gradient(self.times)


@dataclass(frozen=True)
class Reduction:
    """How a warp request is reduced to a compression (HDP07 §3.1).

    Attributes:
        upsample: integer factor u; working frame w is original frame w / u (or reversed).
        n: working input frame count, u (n0 - 1) + 1.
        m: output frame count (None: unconstrained).
        keys: working keytimes (input frame, output frame), endpoints included, both increasing
            (empty for an unconstrained warp).
        backward: whether working frame w is original frame (n0 - 1) - w / u.
    """

    upsample: int
    n: int
    m: int | None
    keys: tuple[tuple[int, int], ...]
    backward: bool

    def to_source(self, working: np.ndarray, n0: int) -> np.ndarray:
        """Working frames -> original input frames."""
        t = np.asarray(working, dtype=np.float64) / self.upsample
        return (n0 - 1) - t if self.backward else t


# ----------------------------------------------------------------------------------------------------------
# Features (HDP07 §3.2)


@dataclass(frozen=True, eq=False)
class Track:
    """Per-frame quantities the features are built from, box-prefiltered over time (HDP07 §3.2).

    Attributes:
        positions: (F, J, 3) global joint positions.
        angle: (F,) root heading angle about the up axis (radians, unwrapped).
        origin: (F, 3) root position with the up coordinate zeroed (the torso frame's origin).
        up: index of the up axis.
    """

    positions: np.ndarray
    angle: np.ndarray
    origin: np.ndarray
    up: int = 1

    def __len__(self) -> int:
        return len(self.angle)

    def take(self, idx: np.ndarray) -> Track:
        return Track(self.positions[idx], self.angle[idx], self.origin[idx], self.up)

    def sample(self, t: np.ndarray) -> Track:
        """The track linearly interpolated at fractional frames ``t`` (within [0, F-1])."""
        t = np.asarray(t, dtype=np.float64)
        f = len(self)
        if t.size and (t.min() < -1e-9 or t.max() > f - 1 + 1e-9):
            raise ValueError(f"sample times outside [0, {f - 1}]")
        t = np.clip(t, 0.0, f - 1)
        i0 = np.minimum(np.floor(t).astype(np.int64), f - 1)
        i1 = np.minimum(i0 + 1, f - 1)
        w = t - i0
        return Track(
            (1.0 - w)[:, None, None] * self.positions[i0] + w[:, None, None] * self.positions[i1],
            (1.0 - w) * self.angle[i0] + w * self.angle[i1],
            (1.0 - w)[:, None] * self.origin[i0] + w[:, None] * self.origin[i1],
            self.up,
        )

    def smoothed(self, width: int) -> Track:
        """The track box-filtered over ``width`` frames."""
        if width <= 1:
            return self
        return Track(uniform_filter1d(self.positions, width, axis=0, mode="nearest"),
                     uniform_filter1d(self.angle, width, axis=0, mode="nearest"),
                     uniform_filter1d(self.origin, width, axis=0, mode="nearest"), self.up)


def motion_track(motion: Motion, filter_width: int = 5, up: str = "y") -> Track:
    """Global joint positions and the root heading of ``motion``, box-filtered over ``filter_width``.

    HDP07 §3.2: "prefiltering with a uniform low-pass filter was sufficient" against aliasing.
    """
    if filter_width < 1:
        raise ValueError(f"filter_width must be >= 1, got {filter_width}")
    k = axis_index(up)
    gpos, _ = forward_kinematics(motion)
    angle = np.unwrap(heading_angle(motion.rotations[:, 0], up))
    origin = motion.root_positions.copy()
    origin[:, k] = 0.0
    return Track(gpos, angle, origin, k).smoothed(filter_width)


def _turn(v: np.ndarray, angle: np.ndarray, up: int) -> np.ndarray:
    """Rotate vectors v (N, J, 3) by ``angle`` (N,) about axis ``up`` (right-handed)."""
    p, q = (up + 1) % 3, (up + 2) % 3
    c = np.cos(angle)[:, None]
    s = np.sin(angle)[:, None]
    out = v.copy()
    out[..., p] = c * v[..., p] - s * v[..., q]
    out[..., q] = s * v[..., p] + c * v[..., q]
    return out


def _local(tr: Track) -> np.ndarray:
    """(N, J, 3) joint positions in each frame's torso (root heading) frame."""
    return _turn(tr.positions - tr.origin[:, None, :], -tr.angle, tr.up)


def _blocks(ti: Track, tj: Track, tk: Track, root_motion: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unweighted (N, 3J) pose, velocity and acceleration blocks of triples (x_i, x_j, x_k).

    The pose is x_j in its torso frame. With ``root_motion`` the central differences of the global
    positions are expressed in the torso frame of x_j, so the root's travel and turning count as
    velocity; otherwise they are differences of per-frame torso-frame positions.
    """
    pose = _local(tj)
    if root_motion:
        vel = _turn(0.5 * (tk.positions - ti.positions), -tj.angle, tj.up)
        acc = _turn(tk.positions - 2.0 * tj.positions + ti.positions, -tj.angle, tj.up)
    else:
        li, lk = _local(ti), _local(tk)
        vel = 0.5 * (lk - li)
        acc = lk - 2.0 * pose + li
    n = len(pose)
    return pose.reshape(n, -1), vel.reshape(n, -1), acc.reshape(n, -1)


@dataclass(frozen=True)
class FeatureSpec:
    """How triples become feature vectors (HDP07 §3.2).

    Attributes:
        weights: weights of the pose, velocity and acceleration blocks.
        scales: each block is divided by its scale (the reference's RMS spread of that block when
            normalised, so the weights are relative importances independent of units and fps).
        root_motion: see :func:`_blocks`.
    """

    weights: tuple[float, float, float] = (1.0, 1.0, 1.0)
    scales: tuple[float, float, float] = (1.0, 1.0, 1.0)
    root_motion: bool = True

    def combine(self, blocks: tuple[np.ndarray, np.ndarray, np.ndarray]) -> np.ndarray:
        return np.concatenate([w / s * b for w, s, b in zip(self.weights, self.scales, blocks, strict=True)],
                              axis=1)


def _reference_blocks(track: Track, step: float, root_motion: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    r = len(track)
    if r < 3:
        raise ValueError(f"the reference needs at least 3 frames, got {r}")
    t = np.arange(r, dtype=np.float64)
    t = t[(t - step >= -1e-9) & (t + step <= r - 1 + 1e-9)]
    if len(t) == 0:
        raise ValueError(f"the reference ({r} frames) is too short for a step of {step:g} frames")
    return _blocks(track.sample(t - step), track.sample(t), track.sample(t + step), root_motion)


def feature_spec(reference: Track, weights: Sequence[float] = (1.0, 1.0, 1.0), normalize: bool = True,
                 root_motion: bool = True, step: float = 1.0) -> FeatureSpec:
    """The :class:`FeatureSpec` for a reference: block scales from its RMS spread when ``normalize``."""
    w = tuple(float(v) for v in weights)
    if len(w) != 3 or min(w) < 0 or max(w) <= 0:
        raise ValueError(f"weights must be 3 non-negative numbers, not all 0; got {list(weights)}")
    scales = (1.0, 1.0, 1.0)
    if normalize:
        pose, vel, acc = _reference_blocks(reference, step, root_motion)
        pose = pose - pose.mean(axis=0)
        rms = [float(np.sqrt(np.mean(np.sum(b * b, axis=1)))) for b in (pose, vel, acc)]
        scales = tuple(v if v > 1e-12 else 1.0 for v in rms)
    return FeatureSpec(w, scales, root_motion)  # type: ignore[arg-type]


def reference_features(track: Track, spec: FeatureSpec, step: float = 1.0) -> np.ndarray:
    """(R, 3D) reference features from consecutive frames t-h, t, t+h, h = ``step`` (HDP07 §3.2).

    h = 1 at full rate; the §3.3 heuristic uses its coarse output spacing, still sampling every
    reference frame so the coarse model sees all poses.
    """
    return spec.combine(_reference_blocks(track, step, spec.root_motion))


def triple_index(n: int, skip: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """All valid triples as flat indices into an (n, s, s) table: (j, a, b) with i = j-a, k = j+b."""
    j, a, b = np.meshgrid(np.arange(n), np.arange(1, skip + 1), np.arange(1, skip + 1), indexing="ij")
    ok = (j - a >= 0) & (j + b <= n - 1)
    return j[ok], a[ok], b[ok]


@numba.njit(cache=True)
def _triples_kernel(pos, local, angle, up, j, a, b, root_motion, wp, wv, wa, out):  # pragma: no cover - compiled
    """Row t of ``out`` = [wp·pose, wv·vel, wa·acc] of triple (j−a, j, j+b), as :func:`_blocks`
    followed by :meth:`FeatureSpec.combine`, without per-triple temporaries."""
    nj = pos.shape[1]
    p, q = (up + 1) % 3, (up + 2) % 3
    for t in range(j.shape[0]):
        jj = j[t]
        i = jj - a[t]
        k = jj + b[t]
        c = np.cos(angle[jj])
        sn = -np.sin(angle[jj])
        for m in range(nj):
            for d in range(3):
                out[t, 3 * m + d] = wp * local[jj, m, d]
            if root_motion:
                vp = 0.5 * (pos[k, m, p] - pos[i, m, p])
                vq = 0.5 * (pos[k, m, q] - pos[i, m, q])
                ap = pos[k, m, p] - 2.0 * pos[jj, m, p] + pos[i, m, p]
                aq = pos[k, m, q] - 2.0 * pos[jj, m, q] + pos[i, m, q]
                out[t, 3 * (nj + m) + up] = wv * 0.5 * (pos[k, m, up] - pos[i, m, up])
                out[t, 3 * (nj + m) + p] = wv * (c * vp - sn * vq)
                out[t, 3 * (nj + m) + q] = wv * (sn * vp + c * vq)
                out[t, 3 * (2 * nj + m) + up] = wa * (pos[k, m, up] - 2.0 * pos[jj, m, up] + pos[i, m, up])
                out[t, 3 * (2 * nj + m) + p] = wa * (c * ap - sn * aq)
                out[t, 3 * (2 * nj + m) + q] = wa * (sn * ap + c * aq)
            else:
                for d in range(3):
                    out[t, 3 * (nj + m) + d] = wv * 0.5 * (local[k, m, d] - local[i, m, d])
                    out[t, 3 * (2 * nj + m) + d] = wa * (local[k, m, d] - 2.0 * local[jj, m, d] + local[i, m, d])


def triple_features(track: Track, j: np.ndarray, a: np.ndarray, b: np.ndarray, spec: FeatureSpec) -> np.ndarray:
    """(N, 3D) features of output triples (x_{j-a}, x_j, x_{j+b}): HDP07 §3.2 finite differences
    (:func:`_blocks` weighted by ``spec``), built by one compiled pass: O(N·D)."""
    wp, wv, wa = (w / sc for w, sc in zip(spec.weights, spec.scales, strict=True))
    pos = np.ascontiguousarray(track.positions, dtype=np.float64)
    out = np.empty((len(j), 3 * pos.shape[1] * 3))
    _triples_kernel(pos, np.ascontiguousarray(_local(track)), np.asarray(track.angle, np.float64), track.up,
                    np.asarray(j, np.int64), np.asarray(a, np.int64), np.asarray(b, np.int64), spec.root_motion,
                    wp, wv, wa, out)
    return out


@numba.njit(cache=True)
def _kmin_mean(qq, zz, dots, k, out):  # pragma: no cover - compiled
    """out[i] = mean of the k smallest sqrt(max(qq[i] + zz[r] - 2 dots[i, r], 0)) over r."""
    best = np.empty(k)
    for i in range(dots.shape[0]):
        best[:] = np.inf
        for r in range(dots.shape[1]):
            d = qq[i] + zz[r] - 2.0 * dots[i, r]
            if d < best[k - 1]:
                m = k - 1
                while m > 0 and best[m - 1] > d:
                    best[m] = best[m - 1]
                    m -= 1
                best[m] = d
        acc = 0.0
        for m in range(k):
            acc += np.sqrt(max(best[m], 0.0))
        out[i] = acc / k


def knn_mean_distance(queries: np.ndarray, refs: np.ndarray, k: int, batch_cells: int = 1 << 22) -> np.ndarray:
    """(N,) mean Euclidean distance of each query to its k nearest rows of ``refs`` (HDP07 eq. 2).

    Exact, by GEMM: |q - z|² = |q|² + |z|² - 2 q·z in batches of ~``batch_cells`` distances, then
    one compiled pass per row keeping the k smallest (O(N·R·D) for the GEMM + O(N·R·k) for the
    selection). With fewer than k reference rows all of them are used.
    """
    queries = np.asarray(queries, dtype=np.float64)
    refs = np.asarray(refs, dtype=np.float64)
    k = min(k, len(refs))
    if k < 1:
        raise ValueError("need at least one neighbour and one reference feature")
    zz = np.einsum("ij,ij->i", refs, refs)
    out = np.empty(len(queries))
    step = max(1, batch_cells // max(1, len(refs)))
    for s0 in range(0, len(queries), step):
        q = queries[s0:s0 + step]
        _kmin_mean(np.einsum("ij,ij->i", q, q), zz, q @ refs.T, k, out[s0:s0 + step])
    return out


def local_scores(track: Track, ref_feats: np.ndarray, skip: int, spec: FeatureSpec, neighbours: int = 3,
                 batch: int = 1 << 15) -> np.ndarray:
    """(n, s, s) table F[j, a-1, b-1] = f(x_{j-a}, x_j, x_{j+b}); +inf for triples off the input.

    All ~n s² triples of the working input ``track`` are scored against ``ref_feats``
    (:func:`reference_features`) in GEMM batches of ``batch`` triples (HDP07 §3.2, eq. 2).
    """
    n = len(track)
    table = np.full((n, skip, skip), np.inf)
    j, a, b = triple_index(n, skip)
    for s0 in range(0, len(j), batch):
        sl = slice(s0, s0 + batch)
        feats = triple_features(track, j[sl], a[sl], b[sl], spec)
        table[j[sl], a[sl] - 1, b[sl] - 1] = knn_mean_distance(feats, ref_feats, neighbours)
    return table


# ----------------------------------------------------------------------------------------------------------
# Shortest paths (HDP07 §3.3)


@numba.njit(cache=True)
def _fixed_length_kernel(table, lo, hi):  # pragma: no cover - compiled
    """Layered DP c_p(j,k) = min_i c_{p-1}(i,j) + f(i,j,k) over the allowed windows [lo_p, hi_p]."""
    _n, s, _ = table.shape
    n_layers = lo.shape[0]
    width = 0
    for p in range(n_layers):
        width = max(width, hi[p] - lo[p] + 1)
    back = np.zeros((n_layers, width, s), dtype=np.int8)
    prev = np.full((width, s), np.inf)
    cur = np.full((width, s), np.inf)
    # layer 0: vertices (0, k), cost 0 (HDP07 eq. 3)
    for k in range(lo[0], hi[0] + 1):
        if 1 <= k <= s:
            prev[k - lo[0], k - 1] = 0.0
    for p in range(1, n_layers):
        cur[:, :] = np.inf
        for k in range(lo[p], hi[p] + 1):
            for b in range(1, s + 1):
                j = k - b
                if j < lo[p - 1] or j > hi[p - 1]:
                    continue
                best = np.inf
                arg = 0
                for a in range(1, s + 1):
                    v = prev[j - lo[p - 1], a - 1] + table[j, a - 1, b - 1]
                    if v < best:
                        best = v
                        arg = a
                cur[k - lo[p], b - 1] = best
                back[p, k - lo[p], b - 1] = arg
        prev, cur = cur, prev
    return prev, back


@numba.njit(cache=True)
def _dag_kernel(table):  # pragma: no cover - compiled
    """Unconstrained DAG shortest path over vertices (k - b, k) in increasing k."""
    n, s, _ = table.shape
    cost = np.full((n, s), np.inf)
    back = np.zeros((n, s), dtype=np.int8)
    for k in range(1, n):
        for b in range(1, s + 1):
            j = k - b
            if j < 0:
                break
            if j == 0:
                cost[k, b - 1] = 0.0
                continue
            best = np.inf
            arg = 0
            for a in range(1, s + 1):
                if j - a < 0:
                    break
                v = cost[j, a - 1] + table[j, a - 1, b - 1]
                if v < best:
                    best = v
                    arg = a
            cost[k, b - 1] = best
            back[k, b - 1] = arg
    return cost, back


def feasible_windows(n: int, m: int, skip: int, keys: Sequence[tuple[int, int]]) -> tuple[np.ndarray, np.ndarray]:
    """Bounds lo[q] <= y[q] <= hi[q] (q = 0..m-1) implied by the step limits 1..s and the keytimes.

    ``keys`` are (input frame, output frame) pairs, endpoints included. Raises ValueError naming
    the violated constraint when no path exists.
    """
    q = np.arange(m)
    lo = np.zeros(m, dtype=np.int64)
    hi = np.full(m, n - 1, dtype=np.int64)
    for f, o in keys:
        after = q >= o
        lo = np.maximum(lo, np.where(after, f + (q - o), f - skip * (o - q)))
        hi = np.minimum(hi, np.where(after, f + skip * (q - o), f - (o - q)))
    bad = np.flatnonzero(lo > hi)
    if len(bad):
        raise ValueError(
            f"no warp of {n} working input frames into {m} output frames with skip <= {skip} passes "
            f"through keytimes {list(keys)} (first conflict at output frame {int(bad[0])})"
        )
    return lo, hi


def fixed_length_path(table: np.ndarray, m: int, lo: np.ndarray | None = None,
                      hi: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """Shortest path with exactly m-2 edges from a vertex (0, ·) to a vertex (·, n-1) (HDP07 eqs. 3-4).

    ``lo``/``hi`` (m,) bound y[q] (keytimes, the §3.3 band); they default to the reachable range.
    O(m W s²) for windows of width W <= n; backpointers are int8. Returns (path (m,), cost);
    the cost is inf when the windows admit no path.
    """
    n, s, _ = table.shape
    if m < 2:
        raise ValueError(f"the output needs at least 2 frames, got {m}")
    if lo is None or hi is None:
        lo, hi = feasible_windows(n, m, s, [(0, 0), (n - 1, m - 1)])
    lo = np.ascontiguousarray(lo, dtype=np.int64)
    hi = np.ascontiguousarray(hi, dtype=np.int64)
    if lo[0] != 0 or hi[0] != 0 or lo[-1] != n - 1 or hi[-1] != n - 1:
        raise ValueError("the path must start on frame 0 and end on the last frame")
    if m == 2:
        return np.array([0, n - 1]), (0.0 if n - 1 <= s else np.inf)
    last, back = _fixed_length_kernel(np.ascontiguousarray(table, dtype=np.float64), lo[1:], hi[1:])
    row = last[(n - 1) - lo[-1]]
    b = int(np.argmin(row)) + 1
    cost = float(row[b - 1])
    if not np.isfinite(cost):
        return np.zeros(0, dtype=np.int64), np.inf
    path = np.empty(m, dtype=np.int64)
    path[m - 1] = n - 1
    k = n - 1
    for layer in range(m - 2, 0, -1):  # layer of vertex (y[layer], y[layer+1]) in lo[1:] indexing
        a = int(back[layer, k - lo[layer + 1], b - 1])
        k -= b
        path[layer] = k
        b = a
    path[0] = k - b
    return path, cost


def dag_path(table: np.ndarray) -> tuple[np.ndarray, float]:
    """Unconstrained shortest path from a vertex (0, ·) to a vertex (·, n-1): O(n s²) (HDP07 §3.3)."""
    n, _s, _ = table.shape
    if n < 2:
        raise ValueError("the input needs at least 2 frames")
    cost, back = _dag_kernel(np.ascontiguousarray(table, dtype=np.float64))
    b = int(np.argmin(cost[n - 1])) + 1
    total = float(cost[n - 1, b - 1])
    out = [n - 1]
    k = n - 1
    while k - b > 0:
        a = int(back[k, b - 1])
        k -= b
        out.append(k)
        b = a
    out.append(0)
    return np.array(out[::-1], dtype=np.int64), total


def path_cost(table: np.ndarray, path: np.ndarray) -> float:
    """HDP07 eq. 1 for a path, read from a score table."""
    y = np.asarray(path)
    if len(y) < 3:
        return 0.0
    return float(table[y[1:-1], y[1:-1] - y[:-2] - 1, y[2:] - y[1:-1] - 1].sum())


# ----------------------------------------------------------------------------------------------------------
# Reduction to compression (HDP07 §3.1)


def reduce_to_compression(n0: int, m: int | None, keytimes: Sequence[Keytime] = (), skip: int = 8,
                          backward: bool = False) -> Reduction:
    """Choose the upsampling factor and working keytimes that make a request a compression.

    ``keytimes`` are intermediate (input frame, output frame) pairs in original frames (fractional
    values are rounded to the working grid). Forward warps need both coordinates strictly increasing
    and inside the clip; backward warps need the input frames strictly decreasing. Raises ValueError
    naming the violated constraint; nothing is clamped.
    """
    if skip < 1 or skip > 127:
        raise ValueError(f"skip must be in 1..127, got {skip}")
    if n0 < 2:
        raise ValueError(f"the input needs at least 2 frames, got {n0}")
    if m is None:
        if keytimes:
            raise ValueError("keytimes need an output length (--duration or --frames), not --unconstrained")
        return Reduction(1, n0, None, (), backward)
    if m < 2:
        raise ValueError(f"the output needs at least 2 frames, got {m}")
    if n0 - 1 > skip * (m - 1):
        raise ValueError(
            f"output length {m} frames is below n/s: {n0} input frames need at least "
            f"{math.ceil((n0 - 1) / skip) + 1} output frames with skip {skip}"
        )
    pairs = sorted(((float(i), float(o)) for i, o in keytimes), key=lambda io: io[1])
    for i, o in pairs:
        if not (0.0 <= i <= n0 - 1):
            raise ValueError(f"keytime input frame {i:g} is outside the input (0..{n0 - 1})")
        if not (0.0 <= o <= m - 1):
            raise ValueError(f"keytime output frame {o:g} is outside the output (0..{m - 1})")
    # in the working (possibly reversed) input, input frames must increase with output frames
    src = [(n0 - 1 - i if backward else i, o) for i, o in pairs]
    start, end = (0.0, 0.0), (float(n0 - 1), float(m - 1))
    inner = [kt for kt in src if kt != start and kt != end]
    full = [start, *inner, end]
    for (i0, o0), (i1, o1) in itertools.pairwise(full):
        if not (o1 > o0):
            raise ValueError(f"keytimes must have strictly increasing output times (got {o0:g} then {o1:g})")
        if not (i1 > i0):
            direction = "decreasing (backward warp)" if backward else "increasing"
            raise ValueError(f"keytime input times must be strictly {direction} "
                             f"with output time (segment at output {o0:g}..{o1:g})")
    d_in = np.diff([i for i, _ in full])
    d_out = np.diff([o for _, o in full])
    expand = float(np.max(d_out / d_in))
    compress = float(np.max(d_in / d_out))
    u_min = max(1, math.ceil(expand - 1e-9))
    u_max = math.floor(skip / compress + 1e-9)
    if u_min > u_max:
        raise ValueError(
            f"keytimes ask for speeds from 1/{expand:.3g}x to {compress:.3g}x of the input; a warp with "
            f"skip {skip} covers at most a {skip}x range of speeds"
        )
    # an expansion gets headroom to slow down further than the average (HDP07 §4.3 used 4x for V5)
    u = 1 if expand <= 1.0 else min(u_max, max(u_min, math.ceil(2.0 * expand)))
    keys = [(round(i * u), round(o)) for i, o in full]
    for (i0, o0), (i1, o1) in itertools.pairwise(keys):
        if not (o0 < o1 and i0 < i1 and i1 - i0 >= o1 - o0 and i1 - i0 <= skip * (o1 - o0)):
            raise ValueError(
                f"keytimes {full[1:-1]} round to output frames {[o for _, o in keys[1:-1]]}: segment "
                f"{o0}..{o1} would need {i1 - i0} working input frames in {o1 - o0} steps (skip {skip})"
            )
    return Reduction(u, u * (n0 - 1) + 1, m, tuple(keys), backward)


# ----------------------------------------------------------------------------------------------------------
# Postprocessing (HDP07 §3.4)


def smooth_warp(times: np.ndarray, width: int, anchors: Sequence[int] = ()) -> np.ndarray:
    """Moving average of a warp over ``width`` output frames (HDP07 §3.4).

    Each span between anchors (keytime output frames; the ends always) is padded by odd reflection
    about its end values, so the anchors keep their exact times and linear warps are unchanged;
    a strictly increasing warp stays strictly increasing.
    """
    t = np.asarray(times, dtype=np.float64).copy()
    if width <= 1 or len(t) < 3:
        return t
    half = width // 2
    cuts = sorted({0, len(t) - 1, *(int(a) for a in anchors)})
    out = t.copy()
    for c0, c1 in itertools.pairwise(cuts):
        seg = t[c0:c1 + 1]
        h = min(half, len(seg) - 1)
        if h < 1:
            continue
        left = 2.0 * seg[0] - seg[h:0:-1]
        right = 2.0 * seg[-1] - seg[-2:-h - 2:-1]
        padded = np.concatenate([left, seg, right])
        kernel = np.ones(2 * h + 1) / (2 * h + 1)
        out[c0:c1 + 1] = np.convolve(padded, kernel, mode="valid")
    out[cuts] = t[cuts]  # equal in exact arithmetic; remove the round-off
    return out


def apply_warp(motion: Motion, times: np.ndarray, adaptive: bool = True, max_taps: int = 33) -> Motion:
    """Resample ``motion`` at fractional source frames ``times`` (slerp), HDP07 §3.4.

    With ``adaptive``, output frame p is the average of the input over a source window as wide as
    the local compression c_p = (t_{p+1} - t_{p-1}) / 2 frames (a box spanning c_p - 1 frame
    intervals, so nothing changes where c_p <= 1): each window is sampled at evenly spaced taps
    (normalised quaternion mean, hemisphere-aligned).
    """
    times = np.asarray(times, dtype=np.float64)
    base = sample_motion(motion, times)
    if not adaptive or len(times) < 3:
        return base
    c = np.abs(np.gradient(times))
    width = np.maximum(c - 1.0, 0.0)  # a box of c frames spans c - 1 frame intervals
    taps = int(min(max_taps, max(1, math.ceil(width.max()) + 1)))
    if taps <= 1:
        return base
    if taps % 2 == 0:
        taps += 1
    offs = np.linspace(-0.5, 0.5, taps)
    sample_t = np.clip(times[:, None] + width[:, None] * offs[None, :], 0.0, motion.n_frames - 1)
    many = sample_motion(motion, sample_t.ravel())
    m, j = len(times), motion.skeleton.n_joints
    q = many.rotations.reshape(m, taps, j, 4)
    centre = q[:, taps // 2: taps // 2 + 1]
    q = np.where(np.sum(q * centre, axis=-1, keepdims=True) < 0.0, -q, q)
    rot = quat_normalize(q.mean(axis=1))
    root = many.root_positions.reshape(m, taps, 3).mean(axis=1)
    trans = {k: tr.reshape(m, taps, 3).mean(axis=1) for k, tr in many.translations.items()}
    return replace(base, rotations=rot, root_positions=root, translations=trans)


# ----------------------------------------------------------------------------------------------------------
# Drivers


def check_compatible(motion: Motion, reference: Motion) -> None:
    """Same skeleton (names and hierarchy) and a reference of at least 3 frames, else ValueError."""
    a, b = motion.skeleton, reference.skeleton
    if a.n_joints != b.n_joints or a.signature() != b.signature():
        raise ValueError(
            f"input and reference have different skeletons ({a.n_joints} vs {b.n_joints} joints, "
            f"signature {a.signature()} vs {b.signature()}); HDP07 needs the same skeleton"
        )
    if reference.n_frames < 3:
        raise ValueError(f"the reference needs at least 3 frames, got {reference.n_frames}")


def _with_fps(reference: Motion, fps: float) -> Motion:
    return reference if abs(reference.fps - fps) < 1e-9 else resample(reference, fps)


def guided_warp(
    motion: Motion,
    reference: Motion | None = None,
    *,
    n_out: int | None,
    keytimes: Sequence[Keytime] = (),
    params: WarpParams | None = None,
    fast: bool = False,
    backward: bool = False,
    up: str = "y",
    resample_motion: bool = True,
) -> WarpResult:
    """Guided time warp of ``motion`` towards the timing of ``reference`` (HDP07 §3).

    Args:
        motion: the input x_1..x_n.
        reference: the timing model z_1..z_r (same skeleton); None uses the input itself (§4.1).
        n_out: output frame count m (at the input's fps), or None for the unconstrained warp.
        keytimes: intermediate (input frame, output frame) pairs the warp must interpolate.
        params: the warp's parameters (:class:`WarpParams`: skip s, k of the kNN score, prefilter,
            feature weights and normalisation, heuristic rate and band, smoothing).
        fast: use the §3.3 heuristic (coarse solve at 1/``params.heuristic_rate``, then a full-rate
            search within ``params.band`` working frames of it; falls back to the full search if the
            band is empty).
        backward: play the input backwards (keytime input frames then decrease).
        resample_motion: build the output motion (else ``motion`` in the result is None).

    Cost: O(n s² (r + D)) for the scores and O(m n s²) for the path (O(n s²) unconstrained).
    """
    p = params if params is not None else WarpParams()
    skip, neighbours, filter_width = p.skip, p.neighbours, p.filter_width
    reference = motion if reference is None else reference
    check_compatible(motion, reference)
    n0 = motion.n_frames
    red = reduce_to_compression(n0, n_out, keytimes, skip, backward)
    timings: dict[str, float] = {}

    t0 = time.perf_counter()
    track0 = motion_track(motion, filter_width, up)
    ref_track = motion_track(_with_fps(reference, motion.fps), filter_width, up)
    track = track0.sample(red.to_source(np.arange(red.n), n0))
    spec = feature_spec(ref_track, p.weights, p.normalize, p.root_motion)
    ref_f = reference_features(ref_track, spec)
    timings["features"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    table = local_scores(track, ref_f, skip, spec, neighbours)
    timings["objective"] = time.perf_counter() - t0

    used_heuristic = False
    t0 = time.perf_counter()
    if red.m is None:
        path, cost = dag_path(table)
        timings["optimization"] = time.perf_counter() - t0
    else:
        lo, hi = feasible_windows(red.n, red.m, skip, red.keys)
        path, cost = np.zeros(0, dtype=np.int64), np.inf
        if fast:
            coarse = coarse_solution(table, red, skip, p.heuristic_rate)
            if coarse is not None:
                blo, bhi = band_windows(coarse, red.m, p.band, lo, hi)
                if np.all(blo <= bhi):
                    path, cost = fixed_length_path(table, red.m, blo, bhi)
            used_heuristic = bool(np.isfinite(cost))
            timings["heuristic"] = time.perf_counter() - t0
        if not np.isfinite(cost):
            t1 = time.perf_counter()
            path, cost = fixed_length_path(table, red.m, lo, hi)
            timings["optimization"] = time.perf_counter() - t1
        if not np.isfinite(cost):
            raise ValueError("no admissible warp satisfies the constraints")

    t0 = time.perf_counter()
    raw = red.to_source(path, n0)
    anchors = [o for _, o in red.keys]
    times = smooth_warp(raw, p.smooth_width, anchors)
    out = None
    if resample_motion:
        out = replace(apply_warp(motion, times, p.adaptive_smoothing), name=f"{motion.name}_warped", content_hash="",
                      source=None)
    timings["postprocess"] = time.perf_counter() - t0
    keys_src = [(float(red.to_source(np.array([i]), n0)[0]), float(o)) for i, o in red.keys]
    if red.m is None:
        keys_src = [(float(raw[0]), 0.0), (float(raw[-1]), float(len(raw) - 1))]
    return WarpResult(frames=path, raw_times=raw, times=times, cost=float(cost), motion=out,
                      keytimes=keys_src, upsample=red.upsample, backward=red.backward,
                      heuristic=used_heuristic, timings=timings)


@dataclass(frozen=True)
class CoarseSolution:
    """The §3.3 coarse path: ``path`` in coarse input frames, ``step_in`` working frames per coarse
    input frame and ``step_out`` output frames per coarse output frame."""

    path: np.ndarray
    step_in: float
    step_out: float


def coarse_table(table: np.ndarray, nc: int, step_in: float, step_out: float, skip_c: int) -> np.ndarray:
    """(nc, s_c, s_c) scores of the coarse graph over every ``step_in``-th working frame.

    A coarse edge (J-a', J, J+b') turns at frame J from speed a' step_in / step_out to speed
    b' step_in / step_out (working frames per output frame), then plays ``step_out`` - 1 output
    frames at the second speed: it costs the full-rate score of the turn plus ``step_out`` - 1
    times the mean constant-speed score over the frames up to the next coarse vertex, scores at
    fractional speeds bilinearly interpolated between integer steps. Speeds above s and triples off the input are +inf; speeds below 1 (the
    grids' rounding) are read at 1.
    """
    n, s, _ = table.shape
    big = 1e300
    finite = np.where(np.isfinite(table), table, big)
    centre = np.minimum(np.round(np.arange(nc) * step_in).astype(np.int64), n - 1)
    speed = np.arange(1, skip_c + 1) * (step_in / step_out)
    ok = speed <= s + 1e-9  # speeds just below 1 come from rounding the grids: read them at 1
    v = np.clip(speed, 1.0, s)
    lo = np.floor(v).astype(np.int64)
    hi = np.minimum(lo + 1, s)
    w = v - lo
    # interpolate the whole table over a (axis 1) then b (axis 2) at the coarse speeds
    ra = (1.0 - w)[None, :, None] * finite[:, lo - 1, :] + w[None, :, None] * finite[:, hi - 1, :]
    rb = (1.0 - w)[None, None, :] * ra[:, :, lo - 1] + w[None, None, :] * ra[:, :, hi - 1]  # (n, sc, sc)
    # the turn at J, then step_out - 1 output frames at the constant speed b' until the next vertex,
    # costed by the mean constant-speed score over the frames they cover
    steady = rb[:, np.arange(skip_c), np.arange(skip_c)]  # (n, sc): f(j - v, j, j + v)
    good = steady < big * 1e-3  # undefined near the ends of the input: left out of the means
    zero = np.zeros((1, skip_c))
    cum = np.concatenate([zero, np.cumsum(np.where(good, steady, 0.0), axis=0)])
    cnt = np.concatenate([zero, np.cumsum(good, axis=0)])
    cols = np.arange(skip_c)

    def mean_over(start: np.ndarray, stop: np.ndarray, col: np.ndarray) -> np.ndarray:
        """Mean of the defined steady scores over frames start..stop-1 (inf when none)."""
        stop = np.maximum(stop, start)
        c = cnt[stop, col] - cnt[start, col]
        return np.where(c > 0, (cum[stop, col] - cum[start, col]) / np.maximum(c, 1), np.inf)

    ends = np.minimum(np.round((np.arange(nc)[:, None] + np.arange(1, skip_c + 1)[None, :]) * step_in)
                      .astype(np.int64), n - 1)  # (nc, sc) fine frame of the next coarse vertex
    mean = mean_over(np.broadcast_to(centre[:, None] + 1, ends.shape), ends, cols[None, :])
    out = np.minimum(rb[centre], big) + (step_out - 1.0) * np.minimum(mean, big)[:, None, :]
    # edges leaving the first vertex (0, J) also pay for the stretch from frame 0 to J
    first = np.arange(1, min(skip_c, nc - 1) + 1)
    head = mean_over(np.ones_like(first), centre[first] + 1, first - 1)
    out[first, first - 1, :] += (step_out - 1.0) * np.minimum(head, big)[:, None]
    out[out >= big * 1e-3] = np.inf
    out[:, ~ok, :] = np.inf
    out[:, :, ~ok] = np.inf
    jc = np.arange(nc)[:, None, None]
    ac = np.arange(1, skip_c + 1)[None, :, None]
    bc = np.arange(1, skip_c + 1)[None, None, :]
    out[(jc - ac < 0) | (jc + bc > nc - 1)] = np.inf
    return out


def coarse_solution(table: np.ndarray, red: Reduction, skip: int, rate: int = 8) -> CoarseSolution | None:
    """HDP07 §3.3 heuristic: solve the warp on the input and output subsampled by ``rate``.

    The coarse graph's vertices are pairs of every ``rate``-th working frame and its edge weights
    come from the full-rate score table (:func:`coarse_table`), so the coarse objective approximates
    the full one by piecewise-constant speeds. Returns None when the coarse problem is infeasible.
    """
    m, n = red.m, red.n
    if m is None:
        raise ValueError("the heuristic needs an output length")
    mc = max(2, math.ceil((m - 1) / rate) + 1)
    nc = max(2, math.ceil((n - 1) / rate) + 1)
    step_out = (m - 1) / (mc - 1)
    step_in = (n - 1) / (nc - 1)
    skip_c = max(math.ceil((nc - 1) / (mc - 1)), min(127, math.floor(skip * step_out / step_in)))
    keys_c = [(round(i / step_in), round(o / step_out)) for i, o in red.keys]
    keys_c = [keys_c[0]] + [kc for kc in keys_c[1:-1] if 0 < kc[1] < mc - 1] + [(nc - 1, mc - 1)]
    try:
        lo, hi = feasible_windows(nc, mc, skip_c, keys_c)
    except ValueError:
        lo, hi = feasible_windows(nc, mc, skip_c, [keys_c[0], keys_c[-1]])
    path, cost = fixed_length_path(coarse_table(table, nc, step_in, step_out, skip_c), mc, lo, hi)
    return CoarseSolution(path, step_in, step_out) if np.isfinite(cost) else None


def band_windows(coarse: CoarseSolution, m: int, band: int, lo: np.ndarray, hi: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Full-rate windows: within ``band`` working frames of the interpolated coarse path, within lo/hi."""
    q_out = np.arange(len(coarse.path)) * coarse.step_out
    guess = np.interp(np.arange(m), q_out, coarse.path * coarse.step_in)
    blo = np.maximum(lo, np.floor(guess - band).astype(np.int64))
    bhi = np.minimum(hi, np.ceil(guess + band).astype(np.int64))
    return blo, bhi


def linear_warp(motion: Motion, n_out: int, keytimes: Sequence[Keytime] = (), adaptive: bool = True,
                resample_motion: bool = True) -> WarpResult:
    """The spline-free baseline: a piecewise-linear warp through the keytimes (HDP07 §4.1, Fig. 2)."""
    n0 = motion.n_frames
    if n_out < 2:
        raise ValueError(f"the output needs at least 2 frames, got {n_out}")
    full = [(0.0, 0.0), *sorted((float(i), float(o)) for i, o in keytimes), (float(n0 - 1), float(n_out - 1))]
    ins = np.array([i for i, _ in full])
    outs = np.array([o for _, o in full])
    if np.any(np.diff(outs) <= 0) or np.any(np.diff(ins) <= 0):
        raise ValueError("keytimes must be strictly increasing in input and output time")
    times = np.interp(np.arange(n_out), outs, ins)
    out = replace(apply_warp(motion, times, adaptive), name=f"{motion.name}_linear") if resample_motion else None
    return WarpResult(frames=np.round(times).astype(np.int64), raw_times=times, times=times, cost=0.0,
                      motion=out, keytimes=list(zip(ins.tolist(), outs.tolist(), strict=True)))


def pose_error(a: Motion, b: Motion, up: str = "y") -> float:
    """RMS distance of heading-frame joint positions between two equally long motions (file units)."""
    if a.n_frames != b.n_frames:
        raise ValueError(f"motions differ in length ({a.n_frames} vs {b.n_frames} frames)")
    pa = _local(motion_track(a, 1, up))
    pb = _local(motion_track(b, 1, up))
    return float(np.sqrt(np.mean(np.sum((pa - pb) ** 2, axis=-1))))


__all__ = [
    "CoarseSolution",
    "FeatureSpec",
    "Reduction",
    "Track",
    "WarpResult",
    "apply_warp",
    "band_windows",
    "check_compatible",
    "coarse_solution",
    "coarse_table",
    "dag_path",
    "feasible_windows",
    "feature_spec",
    "fixed_length_path",
    "guided_warp",
    "knn_mean_distance",
    "linear_warp",
    "local_scores",
    "motion_track",
    "path_cost",
    "pose_error",
    "reduce_to_compression",
    "reference_features",
    "smooth_warp",
    "triple_features",
    "triple_index",
]
