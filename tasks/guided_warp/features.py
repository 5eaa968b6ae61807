"""Features of frame triples and their local scores (HDP07 §3.2, eqs. 1-2; design §7)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from motionweb.store.kinematics import (
    axis_index,
    forward_kinematics,
    heading_angle,
)
from motionweb.store.numba_cache import njit
from motionweb.store.motion import Motion
from scipy.ndimage import uniform_filter1d


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


def torso_positions(tr: Track) -> np.ndarray:
    """(N, J, 3) joint positions in each frame's torso (root heading) frame."""
    return _turn(tr.positions - tr.origin[:, None, :], -tr.angle, tr.up)


def triple_blocks(ti: Track, tj: Track, tk: Track, root_motion: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unweighted (N, 3J) pose, velocity and acceleration blocks of triples (x_i, x_j, x_k).

    The pose is x_j in its torso frame. With ``root_motion`` the central differences of the global
    positions are expressed in the torso frame of x_j, so the root's travel and turning count as
    velocity; otherwise they are differences of per-frame torso-frame positions.
    """
    pose = torso_positions(tj)
    if root_motion:
        vel = _turn(0.5 * (tk.positions - ti.positions), -tj.angle, tj.up)
        acc = _turn(tk.positions - 2.0 * tj.positions + ti.positions, -tj.angle, tj.up)
    else:
        li, lk = torso_positions(ti), torso_positions(tk)
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
        root_motion: see :func:`triple_blocks`.
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
    return triple_blocks(track.sample(t - step), track.sample(t), track.sample(t + step), root_motion)


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


@njit(cache=True)
def _triples_kernel(pos, local, angle, up, j, a, b, root_motion, wp, wv, wa, out):  # pragma: no cover - compiled
    """Row t of ``out`` = [wp·pose, wv·vel, wa·acc] of triple (j−a, j, j+b), as :func:`triple_blocks`
    followed by :meth:`FeatureSpec.combine`, without per-triple temporaries.

    Bounds: writes columns < 9·J of rows t < N of ``out`` (N, 9J); reads frames j − a ≥ 0 and
    j + b < F (checked by :func:`triple_features`)."""
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
    (:func:`triple_blocks` weighted by ``spec``), built by one compiled pass: O(N·D)."""
    wp, wv, wa = (w / sc for w, sc in zip(spec.weights, spec.scales, strict=True))
    pos = np.ascontiguousarray(track.positions, dtype=np.float64)
    j, a, b = (np.asarray(v, np.int64).reshape(-1) for v in (j, a, b))
    if not len(j) == len(a) == len(b):
        raise ValueError(f"triples need as many a and b as j, got {len(j)}, {len(a)}, {len(b)}")
    if len(j) and (np.min(j - a) < 0 or np.max(j + b) >= len(pos) or np.min(a) < 0 or np.min(b) < 0):
        raise ValueError(f"a triple (j − a, j, j + b) leaves the track's {len(pos)} frames")
    out = np.empty((len(j), 3 * pos.shape[1] * 3))
    _triples_kernel(pos, np.ascontiguousarray(torso_positions(track)), np.asarray(track.angle, np.float64), track.up,
                    j, a, b, spec.root_motion,
                    wp, wv, wa, out)
    return out


@njit(cache=True)
def _kmin_mean(qq, zz, dots, k, out):  # pragma: no cover - compiled
    """out[i] = mean of the k smallest sqrt(max(qq[i] + zz[r] - 2 dots[i, r], 0)) over r.

    Bounds: k ≥ 1 slots of scratch (checked by :func:`knn_mean_distance`); writes out[:len(dots)]."""
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
