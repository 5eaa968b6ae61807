"""Frame distance grids as matrix products (design §3, KG04 §3.1, metric of Kovar et al. 2002).

For frame clouds ``p`` (of clip A) and ``p'`` (of clip B) with weights ``w`` summing to 1, the
weighted squared distance after the best rotation about the vertical axis plus horizontal
translation of ``p'`` onto ``p`` is closed form once the horizontal coordinates of each cloud are
centred on their weighted mean::

    A = Σ w (x x' + z z'),  B = Σ w (x z' − z x'),  Y = Σ w y y'
    D = Σ w |p|² + Σ w |p'|² − 2 (sqrt(A² + B²) + Y),   θ = atan2(B, A)

Over a grid, A and B are GEMMs of ``w·[x, z]`` (Fa, 2P) against ``[x', z']`` and ``[z', −x']``
(2P, Fb), and Y one of ``w·y`` (Fa, P) against ``y'`` (P, Fb). Centring every cloud first is
the same as subtracting the rank-one terms ``m_x m_x'ᵀ + m_z m_z'ᵀ`` from the uncentred products;
doing it on the features (O(F·P)) is cheaper and better conditioned. A common vertical shift of
both clips leaves D unchanged and keeps float32 round-off small. Cost: ``10·Fa·Fb·P`` flops of
GEMM plus one fused elementwise pass per cell; memory one tile of buffers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from motionweb.store.cache import array_bytes
from motionweb.store.numba_cache import njit

DTypeLike = type[np.floating] | np.dtype | str


@dataclass(frozen=True)
class PreparedFeatures:
    """One clip's clouds as GEMM operands (centred horizontally, vertically shifted by ``y0``).

    Attributes:
        left: (F, 2P) ``w·[x, z]``, the A/B operand when this clip indexes rows.
        left_y: (F, P) ``w·y``.
        right: (F, 2P) ``[x, z]``, the A operand when this clip indexes columns.
        right_rot: (F, 2P) ``[z, −x]``, the B operand when this clip indexes columns.
        right_y: (F, P) ``y``.
        norms: (F,) ``Σ w |p|²`` of each centred cloud.
        centroid: (F, 2) weighted horizontal mean (x, z) that was removed.
        y0: the vertical shift that was removed.
    """

    left: np.ndarray
    left_y: np.ndarray
    right: np.ndarray
    right_rot: np.ndarray
    right_y: np.ndarray
    norms: np.ndarray
    centroid: np.ndarray
    y0: float

    @property
    def n_frames(self) -> int:
        return self.norms.shape[0]


def _check(f: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    f = np.asarray(f)
    w = np.asarray(weights, dtype=np.float64)
    if f.ndim != 3 or f.shape[2] != 3:
        raise ValueError(f"features must be (F, P, 3), got {f.shape}")
    if w.shape != (f.shape[1],):
        raise ValueError(f"weights {w.shape} do not match {f.shape[1]} points per frame")
    s = w.sum()
    if not s > 0:
        raise ValueError("point weights must have a positive sum")
    return f, w / s


def _heights(f: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(F,) weighted mean height of each cloud (``w`` normalised)."""
    return np.asarray(f[:, :, 1], dtype=np.float64) @ w


def _shared_height(heights: list[np.ndarray]) -> float:
    ys = [h for h in heights if len(h)]
    return float(np.mean(np.concatenate(ys))) if ys else 0.0


def vertical_shift(*features: np.ndarray, weights: np.ndarray) -> float:
    """A common vertical offset for clips compared together (their weighted mean height)."""
    w = np.asarray(weights, dtype=np.float64)
    w = w / w.sum()
    return _shared_height([_heights(f, w) for f in features])


@njit(cache=True, nogil=True)
def _shift_heights(y, xx, zz, w, y0, total, left_y, right_y) -> None:
    """One pass over (F, P) clouds shifted down by ``y0`` (d = y − y0): ``total = xx + d² + zz``
    (float64, the terms of the norms), ``left_y = d·w`` and ``right_y = d`` (the output's dtype).

    The same operations, in the same order and precision, as the NumPy expressions they replace
    (``(xx + d*d) + zz``, ``(d*w).astype``), so the operands are the same bytes (tested); no
    fastmath, so nothing is reordered or fused.

    Bounds: every array is (F, P) as ``y`` (``w``: (P,)), checked by :meth:`ClipOperands.prepare`,
    which allocates the outputs.
    """
    for f in range(y.shape[0]):
        for p in range(y.shape[1]):
            d = y[f, p] - y0
            total[f, p] = xx[f, p] + d * d + zz[f, p]
            left_y[f, p] = d * w[p]
            right_y[f, p] = d


@dataclass(frozen=True)
class ClipOperands:
    """Everything of :func:`prepare_features` that does not depend on the vertical shift ``y0``.

    Computed once per clip and rate (O(F·P)); :meth:`prepare` then finishes the operands for one
    ``y0`` with a few elementwise passes, and :func:`prepare_operands_pair` for a pair of clips
    with their shared ``y0`` — the same arrays as :func:`prepare_pair`, at a fraction of its
    per-pair cost when a clip is compared with many others (an index chunk, KG04 §3.1).
    """

    w: np.ndarray  # (P,) weights normalised to sum 1
    xx: np.ndarray  # (F, P) x² of the horizontally centred cloud, float64
    zz: np.ndarray  # (F, P) z²
    y: np.ndarray  # (F, P) heights, float64
    heights: np.ndarray  # (F,) weighted mean heights (terms of vertical_shift)
    left: np.ndarray
    right: np.ndarray
    right_rot: np.ndarray
    centroid: np.ndarray
    dtype: np.dtype

    @classmethod
    def by_rate(cls, features: dict[float, np.ndarray], weights: np.ndarray) -> dict[float, ClipOperands]:
        """:meth:`of` at every rate of a clip's features ({rate: (F_r, P, 3)})."""
        return {r: cls.of(f, weights) for r, f in features.items()}

    @classmethod
    def of(cls, f: np.ndarray, weights: np.ndarray, dtype: DTypeLike = np.float32) -> ClipOperands:
        f, w = _check(f, weights)
        dt = np.dtype(dtype)
        p = np.asarray(f, dtype=np.float64)
        x, z = p[:, :, 0], p[:, :, 2]
        cx = x @ w
        cz = z @ w
        x = x - cx[:, None]
        z = z - cz[:, None]
        return cls(
            w=w, xx=x * x, zz=z * z, y=np.ascontiguousarray(p[:, :, 1]), heights=_heights(f, w),
            left=np.ascontiguousarray(np.concatenate([x * w, z * w], axis=1), dtype=dt),
            right=np.ascontiguousarray(np.concatenate([x, z], axis=1), dtype=dt),
            right_rot=np.ascontiguousarray(np.concatenate([z, -x], axis=1), dtype=dt),
            centroid=np.stack([cx, cz], axis=1),
            dtype=dt,
        )

    @property
    def n_frames(self) -> int:
        return self.y.shape[0]

    @property
    def nbytes(self) -> int:
        """Bytes of its arrays, about 48·F·P (what the index workers' operand cache counts)."""
        return array_bytes(self.w, self.xx, self.zz, self.y, self.heights, self.left, self.right, self.right_rot,
                           self.centroid)

    def prepare(self, y0: float = 0.0) -> PreparedFeatures:
        """The GEMM operands with heights shifted by ``y0``: one fused O(F·P) pass
        (:func:`_shift_heights`) and one matrix-vector product for the norms."""
        f, p = self.y.shape
        total = np.empty((f, p))
        left_y = np.empty((f, p), self.dtype)
        right_y = np.empty((f, p), self.dtype)
        _shift_heights(self.y, self.xx, self.zz, self.w, float(y0), total, left_y, right_y)
        return PreparedFeatures(
            left=self.left,
            left_y=left_y,
            right=self.right,
            right_rot=self.right_rot,
            right_y=right_y,
            norms=(total @ self.w).astype(self.dtype),
            centroid=self.centroid,
            y0=float(y0),
        )


def prepare_features(f: np.ndarray, weights: np.ndarray, y0: float = 0.0,
                     dtype: DTypeLike = np.float32) -> PreparedFeatures:
    """GEMM operands of one clip's clouds (O(F·P)); use the same ``y0`` for clips compared."""
    return ClipOperands.of(f, weights, dtype).prepare(y0)


def prepare_operands_pair(oa: ClipOperands, ob: ClipOperands) -> tuple[PreparedFeatures, PreparedFeatures]:
    """:func:`prepare_pair` from per-clip operands (``ob`` may be ``oa``): O((Fa + Fb)·P)."""
    y0 = _shared_height([oa.heights, ob.heights])
    pa = oa.prepare(y0)
    return pa, pa if ob is oa else ob.prepare(y0)


def prepare_pair(fa: np.ndarray, fb: np.ndarray, weights: np.ndarray,
                 dtype: DTypeLike = np.float32) -> tuple[PreparedFeatures, PreparedFeatures]:
    """Operands for a pair of clips with a shared vertical shift (``fb`` may be ``fa``)."""
    oa = ClipOperands.of(fa, weights, dtype)
    return prepare_operands_pair(oa, oa if fb is fa else ClipOperands.of(fb, weights, dtype))


@njit(cache=True, fastmath=True, nogil=True)
def _combine(aa: np.ndarray, bb: np.ndarray, yy: np.ndarray, na: np.ndarray, nb: np.ndarray,
             out: np.ndarray) -> None:
    """out = max(0, na_i + nb_j − 2 (sqrt(A² + B²) + Y)), one fused pass.

    Bounds: writes only ``out``'s own (r, c) cells; aa, bb, yy are its shape (one GEMM each)."""
    r, c = out.shape
    for i in range(r):
        ni = na[i]
        for j in range(c):
            a = aa[i, j]
            b = bb[i, j]
            d = ni + nb[j] - 2.0 * (np.sqrt(a * a + b * b) + yy[i, j])
            out[i, j] = max(0.0, d)


def _take(m: np.ndarray, idx: slice | np.ndarray) -> np.ndarray:
    return m[idx]


def distance_prepared(pa: PreparedFeatures, pb: PreparedFeatures, rows: slice | np.ndarray,
                      cols: slice | np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """D over the rectangle ``rows × cols`` (slices or index arrays): three GEMMs (A, B, Y) with
    no copies of the operands, then one fused elementwise pass; the caller tiles."""
    la = _take(pa.left, rows)
    na = _take(pa.norms, rows)
    ry = _take(pb.right_y, cols)
    nb = _take(pb.norms, cols)
    aa = np.matmul(la, _take(pb.right, cols).T)
    bb = np.matmul(la, _take(pb.right_rot, cols).T)
    yy = np.matmul(_take(pa.left_y, rows), ry.T)
    if out is None:
        out = np.empty((la.shape[0], ry.shape[0]), dtype=la.dtype)
    _combine(aa, bb, yy, na, nb, out)
    return out


def distance_grid(fa: np.ndarray, fb: np.ndarray, weights: np.ndarray,
                  dtype: DTypeLike = np.float32, tile: int = 2048) -> np.ndarray:
    """The full (Fa, Fb) grid of frame distances (design §3), tile by tile.

    ``fa``, ``fb``: (F, P, 3) clouds from ``tasks.features.clip_features``; ``weights``: (P,).
    O(Fa·Fb·P) flops (≈10·Fa·Fb·P) at GEMM speed; O(Fa·Fb) output memory. Values are squared
    metres (weighted mean squared point distance after alignment), tiny negatives clamped to 0.
    """
    return distance_grid_prepared(*prepare_pair(fa, fb, weights, dtype), tile=tile)


def distance_grid_prepared(pa: PreparedFeatures, pb: PreparedFeatures, tile: int = 2048) -> np.ndarray:
    """:func:`distance_grid` from prepared operands (e.g. :func:`prepare_operands_pair`)."""
    fa_n, fb_n = pa.n_frames, pb.n_frames
    grid = np.empty((fa_n, fb_n), dtype=pa.norms.dtype)
    for r0 in range(0, fa_n, tile):
        r1 = min(r0 + tile, fa_n)
        for c0 in range(0, fb_n, tile):
            c1 = min(c0 + tile, fb_n)
            distance_prepared(pa, pb, slice(r0, r1), slice(c0, c1), out=grid[r0:r1, c0:c1])
    return grid


def distance_block(fa: np.ndarray, fb: np.ndarray, weights: np.ndarray, rows: slice | np.ndarray,
                   cols: slice | np.ndarray, dtype: DTypeLike = np.float32) -> np.ndarray:
    """D on ``rows × cols`` only (the same values ``distance_grid`` would give there).

    Convenience wrapper preparing both clips each call; for many blocks prepare once with
    :func:`prepare_pair` and call :func:`distance_prepared`.
    """
    pa, pb = prepare_pair(fa, fb, weights, dtype)
    return distance_prepared(pa, pb, rows, cols)


def rigid_align_2d(p: np.ndarray, q: np.ndarray, weights: np.ndarray) -> tuple[float, np.ndarray, float]:
    """Best rotation about the vertical (y) axis and horizontal translation taking cloud q to p.

    Returns ``(theta, t, d)``: the right-handed angle about +y, the (x, z) translation applied
    after the rotation, and the weighted squared distance after alignment (KG04 §3.1).
    """
    w = np.asarray(weights, dtype=np.float64)
    w = w / w.sum()
    p = np.asarray(p, dtype=np.float64)
    q = np.asarray(q, dtype=np.float64)
    cp = np.array([p[:, 0] @ w, p[:, 2] @ w])
    cq = np.array([q[:, 0] @ w, q[:, 2] @ w])
    x, z = p[:, 0] - cp[0], p[:, 2] - cp[1]
    x2, z2 = q[:, 0] - cq[0], q[:, 2] - cq[1]
    a = np.sum(w * (x * x2 + z * z2))
    b = np.sum(w * (x * z2 - z * x2))
    theta = float(np.arctan2(b, a))
    c, s = np.cos(theta), np.sin(theta)
    rq = np.array([c * cq[0] + s * cq[1], -s * cq[0] + c * cq[1]])
    t = cp - rq
    qx = c * q[:, 0] + s * q[:, 2] + t[0]
    qz = -s * q[:, 0] + c * q[:, 2] + t[1]
    d = float(np.sum(w * ((p[:, 0] - qx) ** 2 + (p[:, 1] - q[:, 1]) ** 2 + (p[:, 2] - qz) ** 2)))
    return theta, t, d


@njit(cache=True, fastmath=True, nogil=True, inline="always")
def _cell_value(left, left_y, na, right, right_y, nb, i, j) -> float:
    """D at cell (i, j): the same closed form as the GEMM path, as three dot products over the P
    points (float32 products, float64 sums). Inlined, at numba's level, into :func:`cell_distance`
    and :func:`distance_row`, which compile it with the same fastmath flags: LLVM vectorizes the
    sums over the points the same way in both (tests/tasks/test_features_distance.py checks the
    bytes for P = 1 … 139). Not to be called from a function compiled with other flags."""
    p = left_y.shape[1]
    a = 0.0
    b = 0.0
    y = 0.0
    for q in range(p):
        wx = left[i, q]
        wz = left[i, p + q]
        x = right[j, q]
        z = right[j, p + q]
        a += wx * x + wz * z
        b += wx * z - wz * x
        y += left_y[i, q] * right_y[j, q]
    d = na[i] + nb[j] - 2.0 * (np.sqrt(a * a + b * b) + y)
    return max(0.0, d)


@njit(cache=True, fastmath=True, nogil=True)
def cell_distance(left, left_y, na, right, right_y, nb, i, j) -> float:
    """D at one cell (:func:`_cell_value`; KG04 §3.1 eq. 1)."""
    return _cell_value(left, left_y, na, right, right_y, nb, i, j)


@njit(cache=True, fastmath=True, nogil=True)
def distance_row(left, left_y, na, right, right_y, nb, i, j0, n, out, o) -> None:
    """D at the ``n`` cells (i, j0 … j0 + n − 1) of one row into ``out[o : o + n]`` (KG04 §3.1 eq. 1).

    The same bytes as :func:`cell_distance` cell by cell, one call per run of cells instead of one
    per cell: a call passes six arrays by value, ~20 ns of a ~60 ns cell at P = 110
    (bench/index_scale.py prints the per-cell rate). O(n·P).

    Bounds: the caller keeps i < Fa, j0 ≥ 0, j0 + n ≤ Fb and o + n ≤ len(out).
    """
    for u in range(n):
        out[o + u] = _cell_value(left, left_y, na, right, right_y, nb, i, j0 + u)


@njit(cache=True, nogil=True)
def _cells_kernel(left, left_y, na, right, right_y, nb, rows, cols, out) -> None:
    """Bounds: writes out[:len(rows)] (``out``, ``cols`` as long, checked by :func:`distance_cells`);
    reads rows < Fa, cols < Fb."""
    for k in range(rows.shape[0]):
        out[k] = cell_distance(left, left_y, na, right, right_y, nb, rows[k], cols[k])


@njit(cache=True, nogil=True)
def _grid_kernel(left, left_y, na, right, right_y, nb, out) -> None:
    """Bounds: writes out[i, j] for i < out.shape[0] ≤ Fa, j < out.shape[1] ≤ Fb (checked by
    :func:`distance_grid_cells`, which allocates ``out`` as (Fa, Fb))."""
    for i in range(out.shape[0]):
        distance_row(left, left_y, na, right, right_y, nb, i, 0, out.shape[1], out[i], 0)


def distance_grid_cells(pa: PreparedFeatures, pb: PreparedFeatures) -> np.ndarray:
    """The full (Fa, Fb) grid cell by cell (:func:`cell_distance`, float64 sums, stored as the
    operands' dtype): the values the finer levels of a match web evaluate, the same bytes on the
    x86-64 CPUs tests/tasks/test_cpu_bytes.py compiles for (KG04 §3.1-3.2, the coarsest level of
    Fig. 8; ``cell_distance`` is compiled with fastmath, so other architectures are untested).

    The GEMM path (:func:`distance_grid_prepared`) is ~4x faster but sums in float32 in the order
    of the BLAS kernel the CPU gets, so its last bits, and through them a web's minima, chains and
    bridges, differed between machines of one cluster (bench/cpu_bytes.py). O(Fa·Fb·P), one thread.
    """
    out = np.empty((pa.n_frames, pb.n_frames), dtype=pa.norms.dtype)
    _grid_kernel(pa.left, pa.left_y, pa.norms, pb.right, pb.right_y, pb.norms, out)
    return out


def distance_cells(pa: PreparedFeatures, pb: PreparedFeatures, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """D at scattered cells ``(rows[k], cols[k])`` (no GEMM: O(P) per cell, single thread).

    For coarse-to-fine search regions, whose cells are few and thin, this evaluates exactly the
    cells needed; whole rectangles are faster with :func:`distance_prepared`.
    """
    r = np.ascontiguousarray(rows, dtype=np.int64)
    c = np.ascontiguousarray(cols, dtype=np.int64)
    if r.shape != c.shape or r.ndim != 1:
        raise ValueError(f"rows and cols must be two 1-D arrays of one length, got {r.shape} and {c.shape}")
    if len(r) and (r.min() < 0 or r.max() >= pa.n_frames or c.min() < 0 or c.max() >= pb.n_frames):
        raise ValueError(f"cells outside the {pa.n_frames} × {pb.n_frames} grid")
    out = np.empty(r.shape[0], dtype=pa.norms.dtype)
    _cells_kernel(pa.left, pa.left_y, pa.norms, pb.right, pb.right_y, pb.norms, r, c, out)
    return out
