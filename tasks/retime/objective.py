"""The baked objective of MPS06 Eqn. 14 and its compiled kernels (design §8, MPS06 §3.4, §3.6).

:func:`bake` keeps λ at every polygon vertex (from its LP) and at the centre (≈ original timing),
interpolates barycentrically in a fan triangulation around the centre (MPS06 §3.4, Fig. 5), so τ is
affine in (p̈, ṗ²) per fan sector and β‖τ − τ'‖² is six coefficients per sector and frame (MPS06
§3.6), torques in units of their limits; the distance to the polygon is priced per frame by the
root force a unit of (p̈, ṗ²) asks for. :func:`objective_kernel` sums the density over the samples
of a timing with its gradient in one compiled pass.

Cost: baking O(F · K · nv · nλ); one density evaluation O(K) (independent of the number of dofs).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from motionweb.tasks.retime.contacts import Contacts
from motionweb.tasks.retime.polygons import N_ROOT, FeasiblePolygons, polygon_area
from motionweb.store.numba_cache import njit


@dataclass(frozen=True, eq=False)
class BakedObjective:
    """Per-frame piecewise-quadratic objective in x = (p̈, ṗ²) (MPS06 §3.6), padded to K sectors.

    Attributes:
        verts: (F, K, 2) polygon vertices (padded by repeating the last); count: (F,) vertices
            before the padding; inv_len2: (F, K) 1 / squared length of edge k → k+1 (0 for
            degenerate edges); solid: (F,) area > 0.
        center: (F, 2); theta0: (F,) angle of the first vertex about the centre; theta: (F, K)
            vertex angles relative to theta0 in [0, 2π) (padding 10).
        coef: (F, K, 6) torque-term coefficients of p̈², p̈ṗ², ṗ⁴, p̈, ṗ², 1 per sector (β included).
        lam_center: (F, nλ); lam_slope: (F, K, nλ, 2): λ(x) = λ_c + Λ_k (x − c) in sector k.
        alpha: (F,) per-frame weight of the squared distance to the polygon (α times the frame's
            root force per unit of (p̈, ṗ²), squared, see :func:`bake`); beta: torque weight.
    """

    verts: np.ndarray
    count: np.ndarray
    inv_len2: np.ndarray
    solid: np.ndarray
    center: np.ndarray
    theta0: np.ndarray
    theta: np.ndarray
    coef: np.ndarray
    lam_center: np.ndarray
    lam_slope: np.ndarray
    alpha: np.ndarray
    beta: float

    @property
    def n_frames(self) -> int:
        return self.verts.shape[0]


def bake(polys: FeasiblePolygons, A: np.ndarray, B: np.ndarray, C: np.ndarray, contacts: Contacts,
         tau_target: np.ndarray, alpha: float, beta: float, tau_scale: np.ndarray) -> BakedObjective:
    """Fan-triangulated contact model and six coefficients per sector (MPS06 §3.4, §3.6).

    The torque term of MPS06 Eqn. 14 is made dimensionless: each generalized force is divided by
    ``tau_scale`` (its torque limit; body weight on the root rows) and the sum by nv, so β‖τ − τ'‖²
    is β times the mean squared deviation in units of the limits, and α, β compare unit-free
    quantities whatever the body's size. With D = diag(1/tau_scale)/√nv and τ(x) − τ' =
    a_k p̈ + b_k ṗ² + e_k in sector k (a, b, e scaled by D), the term is β(a·a p̈² + 2a·b p̈ṗ² +
    b·b ṗ⁴ + 2a·e p̈ + 2b·e ṗ² + e·e).

    The feasibility term is priced in force as well: a step δ = [p̈, ṗ²] − c out of frame i's
    polygon asks the unactuated root for [A, B]_root δ that no contact can supply, so the frame's
    weight is α σ_i² with σ_i = ‖[A_i, B_i]_root / tau_scale_root‖₂ (body weights per unit of
    (p̈, ṗ²)). A flight frame, whose whole weight rides on ṗ², pays ~1 per unit; a still frame
    (q' = q'' = 0) only the floor of 0.1 body weight per unit that keeps it inside the box
    (``PolygonParams`` ``speed_max``, ``pdd_max``) — so the squared-distance penalty of MPS06 Eqn. 14 no longer
    trades a ballistic flight against a standing pose one to one. O(F · K · nv · nλ).
    """
    f = A.shape[0]
    K = max(max((len(v) for v in polys.vertices), default=1), 1)
    nl = contacts.basis.shape[2]
    verts = np.zeros((f, K, 2))
    count = np.ones(f, np.int64)
    theta = np.full((f, K), 10.0)
    theta0 = np.zeros(f)
    coef = np.zeros((f, K, 6))
    slope = np.zeros((f, K, nl, 2))
    solid = np.zeros(f, bool)
    d = 1.0 / (np.asarray(tau_scale, dtype=float) * np.sqrt(A.shape[1]))
    for i in range(f):
        v, lv, c = polys.vertices[i], polys.lambdas[i], polys.center[i]
        k = len(v)
        if k == 0:
            v, lv, k = c[None], polys.center_lambda[i][None], 1
        verts[i, :k] = v
        verts[i, k:] = v[-1]
        count[i] = k
        solid[i] = polygon_area(v) > 1e-12
        ang = np.arctan2(v[:, 1] - c[1], v[:, 0] - c[0])
        theta0[i] = ang[0]
        theta[i, :k] = np.mod(ang - ang[0], 2 * np.pi)
        theta[i, 0] = 0.0
        lc = polys.center_lambda[i]
        if k >= 3:  # sector s spans centre, v_s, v_{s+1}: λ(x) = λ_c + [λ_s − λ_c, λ_{s+1} − λ_c] D_s⁻¹ (x − c)
            r0, r1 = v - c, np.roll(v, -1, axis=0) - c
            det = r0[:, 0] * r1[:, 1] - r1[:, 0] * r0[:, 1]
            ok = np.abs(det) > 1e-12
            inv = np.stack([np.stack([r1[:, 1], -r1[:, 0]], 1), np.stack([-r0[:, 1], r0[:, 0]], 1)], 1)
            inv /= np.where(ok, det, 1.0)[:, None, None]
            dl = np.stack([lv - lc, np.roll(lv, -1, axis=0) - lc], axis=2)  # (k, nλ, 2)
            slope[i, :k] = np.where(ok[:, None, None], dl @ inv, 0.0)
            slope[i, k:] = slope[i, k - 1]
        N = contacts.basis[i]
        L = slope[i]  # (K, nλ, 2)
        a = d[:, None] * (A[i][:, None] - N @ L[:, :, 0].T)  # (nv, K)
        b = d[:, None] * (B[i][:, None] - N @ L[:, :, 1].T)
        e = d[:, None] * ((C[i] - tau_target[i] - N @ lc)[:, None] + N @ (L @ c).T)
        coef[i] = beta * np.stack([(a * a).sum(0), 2 * (a * b).sum(0), (b * b).sum(0), 2 * (a * e).sum(0),
                                   2 * (b * e).sum(0), (e * e).sum(0)], axis=1)
    edge = np.zeros_like(verts)
    for i in range(f):
        k = count[i]
        edge[i, :k] = np.roll(verts[i, :k], -1, axis=0) - verts[i, :k]
    len2 = (edge * edge).sum(axis=2)
    inv_len2 = np.divide(1.0, len2, out=np.zeros_like(len2), where=len2 > 0)
    root = np.stack([A[:, :N_ROOT], B[:, :N_ROOT]], axis=2) / np.asarray(tau_scale, float)[None, :N_ROOT, None]
    sigma = np.linalg.norm(root, ord=2, axis=(1, 2))
    return BakedObjective(verts=verts, count=count, inv_len2=inv_len2, solid=solid, center=polys.center.copy(), theta0=theta0, theta=theta,
                          coef=coef, lam_center=polys.center_lambda.copy(), lam_slope=slope,
                          alpha=alpha * (sigma**2 + 0.1**2), beta=beta)


def sector(obj: BakedObjective, fr: np.ndarray, x: np.ndarray) -> np.ndarray:
    """The fan sector (S,) of frame ``fr[s]``'s polygon that x[s] = (p̈, ṗ²) lies in (by angle about the centre)."""
    c = obj.center[fr]
    ang = np.mod(np.arctan2(x[:, 1] - c[:, 1], x[:, 0] - c[:, 0]) - obj.theta0[fr], 2 * np.pi)
    return np.maximum((obj.theta[fr] <= ang[:, None]).sum(axis=1) - 1, 0)


@njit(cache=True, inline="always")
def _frame_value(verts, count, inv_len2, solid, center, theta0, theta, coef, alpha, fr, x0, x1):  # pragma: no cover
    """Value and d/dx of frame ``fr``'s terms at x = (x0, x1): O(count[fr]), padding skipped."""
    K = count[fr]
    ang = np.arctan2(x1 - center[fr, 1], x0 - center[fr, 0]) - theta0[fr]
    two_pi = 2.0 * np.pi
    ang = ang - two_pi * np.floor(ang / two_pi)
    s = 0
    while s + 1 < K and theta[fr, s + 1] <= ang:  # vertex angles increase
        s += 1
    c = coef[fr, s]
    val = c[0] * x0 * x0 + c[1] * x0 * x1 + c[2] * x1 * x1 + c[3] * x0 + c[4] * x1 + c[5]
    g0 = 2 * c[0] * x0 + c[1] * x1 + c[3]
    g1 = c[1] * x0 + 2 * c[2] * x1 + c[4]
    best, b0, b1 = 1e300, x0, x1
    if solid[fr]:
        # the closest point of a convex polygon lies on an edge whose half-plane x violates (at a
        # vertex, one of its two edges' half-planes is violated), so project on those only
        inside = True
        for k in range(K):
            kn = k + 1 if k + 1 < K else 0
            ax, ay = verts[fr, k, 0], verts[fr, k, 1]
            if (verts[fr, kn, 0] - ax) * (x1 - ay) - (verts[fr, kn, 1] - ay) * (x0 - ax) < 0:
                inside = False
                d, px, py = _edge_point(verts, inv_len2, fr, k, K, x0, x1)
                if d < best:
                    best, b0, b1 = d, px, py
        if inside:
            return val, g0, g1
    else:  # a segment or a point (flight frames): every edge
        for k in range(K):
            d, px, py = _edge_point(verts, inv_len2, fr, k, K, x0, x1)
            if d < best:
                best, b0, b1 = d, px, py
    return val + alpha[fr] * best, g0 + 2 * alpha[fr] * (x0 - b0), g1 + 2 * alpha[fr] * (x1 - b1)


@njit(cache=True, inline="always")
def _edge_point(verts, inv_len2, fr, k, K, x0, x1):  # pragma: no cover - numba
    """Squared distance from x to edge k → k+1 of frame ``fr`` and the closest point on it."""
    ax, ay = verts[fr, k, 0], verts[fr, k, 1]
    kn = k + 1 if k + 1 < K else 0
    ex, ey = verts[fr, kn, 0] - ax, verts[fr, kn, 1] - ay
    t = min(max(((x0 - ax) * ex + (x1 - ay) * ey) * inv_len2[fr, k], 0.0), 1.0)
    px, py = ax + t * ex, ay + t * ey
    return (x0 - px) ** 2 + (x1 - py) ** 2, px, py


@njit(cache=True, inline="always")
def _sample_value(verts, count, inv_len2, solid, center, theta0, theta, coef, alpha, u, x0, x1):  # pragma: no cover
    """Density at source frame ``u`` (linear blend of its two frames): value, d/dx0, d/dx1, d/du.

    Bounds: reads frames 0..F−1 only (F ≥ 1; u is clamped to [0, F − 1], NaN to 0)."""
    f = verts.shape[0]
    ui = max(0.0, u)  # NaN reads frame 0: int(floor(NaN)) would index anywhere
    ui = min(f - 1.0, ui)
    i0 = min(int(np.floor(ui)), max(f - 2, 0))
    i1 = min(i0 + 1, f - 1)
    w = ui - i0
    va, ga0, ga1 = _frame_value(verts, count, inv_len2, solid, center, theta0, theta, coef, alpha, i0, x0, x1)
    vb, gb0, gb1 = _frame_value(verts, count, inv_len2, solid, center, theta0, theta, coef, alpha, i1, x0, x1)
    return (1 - w) * va + w * vb, (1 - w) * ga0 + w * gb0, (1 - w) * ga1 + w * gb1, vb - va


@njit(cache=True)
def _evaluate_kernel(verts, count, inv_len2, solid, center, theta0, theta, coef, alpha, u, x):  # pragma: no cover
    """Bounds: writes rows 0..S−1 of its own (S,) / (S, 2) outputs, S = len(u) = len(x)."""
    n = u.shape[0]
    val = np.empty(n)
    gx = np.empty((n, 2))
    gu = np.empty(n)
    for i in range(n):
        val[i], gx[i, 0], gx[i, 1], gu[i] = _sample_value(verts, count, inv_len2, solid, center, theta0, theta, coef, alpha,
                                                          u[i], x[i, 0], x[i, 1])
    return val, gx, gu


@njit(cache=True)
def objective_kernel(verts, count, inv_len2, solid, center, theta0, theta, coef, alpha, ctrl, w, c, fps, dt
                      ):  # pragma: no cover
    """MPS06 Eqn. 14 summed over samples and its gradient in the control points, in one pass.

    Sample s depends on control points ``ctrl[s]`` (4) with weights ``w[:, s]`` for p, ṗ, p̈
    (MPS06 §3.6: four control points per sample, so the gradient is linear in the samples).

    Bounds: writes ``grad`` (len(c),) at ``ctrl[s]``, indices below len(c) (``TimingSpline.design``
    makes them so; :func:`objective_function`'s callers pass its ``ctrl``).
    """
    n = ctrl.shape[0]
    grad = np.zeros(c.shape[0])
    total = 0.0
    for s in range(n):
        p = 0.0
        pd = 0.0
        pdd = 0.0
        for j in range(4):
            cj = c[ctrl[s, j]]
            p += w[0, s, j] * cj
            pd += w[1, s, j] * cj
            pdd += w[2, s, j] * cj
        v, g0, g1, gu = _sample_value(verts, count, inv_len2, solid, center, theta0, theta, coef, alpha, p * fps, pdd, pd * pd)
        total += v
        g_p = gu * fps * dt
        g_pd = g1 * 2.0 * pd * dt
        g_pdd = g0 * dt
        for j in range(4):
            grad[ctrl[s, j]] += w[0, s, j] * g_p + w[1, s, j] * g_pd + w[2, s, j] * g_pdd
    return total * dt, grad


def evaluate(obj: BakedObjective, u: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Objective density at source frames ``u`` (S,) and x = (p̈, ṗ²) (S, 2), blending frames linearly.

    Returns value (S,), d/dx (S, 2) and d/du (S,). O(S · K), compiled (numba); the numpy
    reference is ``evaluate_numpy`` in tests/naive.py.
    """
    u = np.ascontiguousarray(u, dtype=np.float64).reshape(-1)
    x = np.ascontiguousarray(x, dtype=np.float64).reshape(-1, 2)
    if len(u) != len(x):
        raise ValueError(f"{len(u)} source frames but {len(x)} (p̈, ṗ²) points")
    if len(u) and len(obj.verts) == 0:
        raise ValueError("the objective has no frames to evaluate")
    return _evaluate_kernel(obj.verts, obj.count, obj.inv_len2, obj.solid, obj.center, obj.theta0, obj.theta, obj.coef,
                            obj.alpha, u, x)


def contact_lambda(obj: BakedObjective, frame: int, x: np.ndarray) -> np.ndarray:
    """λ at (p̈, ṗ²) = ``x`` from the fan model of ``frame`` (clipped at 0 outside the polygon)."""
    s = int(sector(obj, np.array([frame]), x[None])[0])
    lam = obj.lam_center[frame] + obj.lam_slope[frame, s] @ (x - obj.center[frame])
    return np.maximum(lam, 0.0)
