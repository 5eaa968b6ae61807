"""The monotone timing spline p(t) and its optimizer (design §8, MPS06 §3.5-3.6).

p(t) (output → source time) is a clamped cubic B-spline per keytime segment with strictly
increasing control points (positive increments by a softmax), so p is strictly monotone and meets
endpoints and keytimes exactly. :func:`optimize_timing` minimizes MPS06 Eqn. 14 sampled ≥ 4 times
per source frame in one compiled pass (value and analytic gradient) with L-BFGS-B.

Cost: one objective evaluation O(S · K) with S samples and K polygon vertices.
"""

from __future__ import annotations

import ctypes
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from typing import Protocol

import numpy as np
from motionweb.tasks.retime.errors import RetimeError
from motionweb.tasks.retime.objective import BakedObjective, objective_kernel
from motionweb.store.numba_cache import njit
from scipy.interpolate import BSpline
from scipy.optimize import minimize


@contextmanager
def single_threaded_blas() -> Iterator[None]:
    """Run the block with the OpenBLAS libraries of numpy and scipy on one thread, then restore.

    Retiming solves tiny problems (L-BFGS-B on ~10² parameters, 2×2 to 60×20 products), where
    OpenBLAS threads only add synchronization: on a loaded 2-core machine scipy's L-BFGS-B ran
    ~50× slower per iteration with its default thread count. The libraries are found among the
    loaded shared objects (``/proc/self/maps``); elsewhere the block runs unchanged.
    """
    libs = []
    try:
        with open("/proc/self/maps") as fh:
            paths = sorted({line.split()[-1] for line in fh if "openblas" in line.lower() and "/" in line})
    except OSError:
        paths = []
    for path in paths:
        lib = ctypes.CDLL(path)
        for suffix in ("64_", ""):
            get = getattr(lib, f"scipy_openblas_get_num_threads{suffix}", None)
            put = getattr(lib, f"scipy_openblas_set_num_threads{suffix}", None)
            if get is not None and put is not None:
                libs.append((put, int(get())))
                put(1)
                break
    try:
        yield
    finally:
        for put, n in libs:
            put(n)


class TimingCurve(Protocol):
    """p(t) of a retiming: ``out[-1]`` its output duration, ``evaluate(z, t)`` p, ṗ, p̈ at times t."""

    out: np.ndarray

    def evaluate(self, z: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...


@dataclass(frozen=True, eq=False)
class TimingSpline:
    """p(t): output seconds → source seconds, clamped cubic B-splines between keytimes.

    Segment k spans output [out[k], out[k+1]] and source [src[k], src[k+1]]; its control points
    are src[k] + cumsum of positive increments (softmax of free parameters times the source span),
    so p is strictly increasing and passes exactly through every keytime.
    """

    out: np.ndarray
    src: np.ndarray
    knots: list[np.ndarray]
    n_ctrl: list[int]

    @classmethod
    def make(cls, out: np.ndarray, src: np.ndarray, knots_per_second: float) -> TimingSpline:
        knots, n_ctrl = [], []
        for k in range(len(out) - 1):
            n_int = max(2, round((src[k + 1] - src[k]) * knots_per_second))
            inner = np.linspace(out[k], out[k + 1], n_int + 1)
            knots.append(np.concatenate([[out[k]] * 3, inner, [out[k + 1]] * 3]))
            n_ctrl.append(n_int + 3)
        return cls(out=np.asarray(out, float), src=np.asarray(src, float), knots=knots, n_ctrl=n_ctrl)

    @property
    def n_params(self) -> int:
        return sum(n - 1 for n in self.n_ctrl)

    def controls(self, z: np.ndarray) -> np.ndarray:
        """The concatenated control points of all segments for parameters ``z``."""
        if np.size(z) != self.n_params:
            raise ValueError(f"the timing spline has {self.n_params} parameters, got {np.size(z)}")
        return _controls(np.asarray(z, float), np.asarray(self.n_ctrl, np.int64), self.src)

    def design(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The 4 control points (S, 4; indices into the concatenated controls) each output time
        depends on and their weights (3, S, 4) for p, ṗ, p̈ (the nonzeros of the design matrices)."""
        t = np.asarray(t, float)
        ctrl = np.zeros((len(t), 4), np.int64)
        w = np.zeros((3, len(t), 4))
        offset = 0
        for k, n in enumerate(self.n_ctrl):
            last = k == len(self.n_ctrl) - 1
            sel = np.flatnonzero((t >= self.out[k]) & ((t <= self.out[k + 1]) if last else (t < self.out[k + 1])))
            tt = t[sel]
            first = np.clip(np.searchsorted(self.knots[k], tt, side="right") - 1, 3, n - 1) - 3
            cols = first[:, None] + np.arange(4)
            spl = BSpline(self.knots[k], np.eye(n), 3, extrapolate=False)
            for d in range(3):
                dense = np.nan_to_num((spl.derivative(d) if d else spl)(tt))
                w[d, sel] = np.take_along_axis(dense, cols, axis=1)
            ctrl[sel] = offset + cols
            offset += n
        return ctrl, w

    def evaluate(self, z: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """p, ṗ, p̈ at output times ``t``."""
        ctrl, w = self.design(t)
        c = self.controls(z)[ctrl]
        return (w[0] * c).sum(axis=1), (w[1] * c).sum(axis=1), (w[2] * c).sum(axis=1)


@njit(cache=True)
def _controls(z, n_ctrl, src):  # pragma: no cover - numba
    """Segment k's controls: src[k] + cumsum of softmax(z_k) · (src[k+1] − src[k]), last = src[k+1].

    Bounds: writes Σ n_ctrl controls into its own output, segment k at oc..oc + n_ctrl[k] − 1;
    reads Σ (n_ctrl − 1) parameters (len(z), checked by ``TimingSpline.controls``)."""
    c = np.empty(n_ctrl.sum())
    o = 0
    oc = 0
    for k in range(n_ctrl.shape[0]):
        n = n_ctrl[k]
        zk = z[o:o + n - 1]
        e = np.exp(zk - zk.max())
        inc = (src[k + 1] - src[k]) / e.sum()
        c[oc] = src[k]
        for i in range(n - 1):
            c[oc + i + 1] = c[oc + i] + inc * e[i]
        c[oc + n - 1] = src[k + 1]
        o += n - 1
        oc += n
    return c


@njit(cache=True)
def _chain(z, grad, n_ctrl, src):  # pragma: no cover - numba
    """Gradient in z from the gradient in the controls of :func:`_controls`.

    Bounds: writes len(z) = Σ (n_ctrl − 1) entries, segment k at o..o + n_ctrl[k] − 2."""
    out = np.empty(z.shape[0])
    o = 0
    oc = 0
    for k in range(n_ctrl.shape[0]):
        n = n_ctrl[k]
        zk = z[o:o + n - 1]
        e = np.exp(zk - zk.max())
        s = e / e.sum()
        g_inc = np.empty(n - 1)
        acc = 0.0
        for i in range(n - 2, -1, -1):  # c_i depends on inc_j for j < i
            acc += grad[oc + i + 1]
            g_inc[i] = acc * (src[k + 1] - src[k])
        sg = (s * g_inc).sum()
        out[o:o + n - 1] = s * g_inc - s * sg
        o += n - 1
        oc += n
    return out


@dataclass(frozen=True, eq=False)
class RetimeResult:
    """A retiming: the timing curve, its parameters, and p, ṗ, p̈ at the output frames.

    Attributes:
        spline, z: the timing curve (a :class:`TimingSpline`, or the path timing's
            ``path_timing.PathCurve`` with no parameters) and its parameters; kind: "spline" or "path".
        t: (T,) output frame times; p, pd, pdd: (T,) source time, ṗ, p̈ there.
        objective: final objective; n_samples: samples used; iterations: L-BFGS iterations;
        seconds: optimization wall time; converged: optimizer success flag.
    """

    spline: TimingCurve
    z: np.ndarray
    t: np.ndarray
    p: np.ndarray
    pd: np.ndarray
    pdd: np.ndarray
    objective: float
    n_samples: int
    iterations: int
    seconds: float
    converged: bool
    message: str = ""
    history: list[float] = field(default_factory=list)
    kind: str = "spline"


def check_keytimes(src_duration: float, duration: float, keytimes: list[tuple[float, float]],
                   speed_max: float) -> tuple[np.ndarray, np.ndarray]:
    """Validated (out, src) knot arrays including both endpoints (RetimeError explains problems)."""
    if not duration > 0:
        raise RetimeError(f"the output duration must be positive, got {duration}")
    kt = sorted(keytimes)
    src = np.array([0.0] + [s for s, _ in kt] + [src_duration])
    out = np.array([0.0] + [o for _, o in kt] + [duration])
    for s, o in kt:
        if not (0 < s < src_duration):
            raise RetimeError(f"keytime source {s:g} s is outside the clip's (0, {src_duration:g}) s")
        if not (0 < o < duration):
            raise RetimeError(f"keytime output {o:g} s is outside the output's (0, {duration:g}) s")
    if np.any(np.diff(src) <= 0) or np.any(np.diff(out) <= 0):
        raise RetimeError("keytimes must increase in both source and output time (p(t) is monotone)")
    ratio = np.diff(src) / np.diff(out)
    if ratio.max() > speed_max:
        k = int(np.argmax(ratio))
        raise RetimeError(f"output span {out[k]:g}-{out[k + 1]:g} s would need {ratio[k]:.2f}x speed; "
                          f"more than the {speed_max:g}x allowed (retime.polygons.speed_max)")
    return out, src


def optimize_timing(obj: BakedObjective, fps: float, src_duration: float, duration: float,
                    keytimes: list[tuple[float, float]] | None = None, *, samples_per_frame: int,
                    knots_per_second: float, speed_max: float, max_iter: int = 2000,
                    free_length: bool = False) -> RetimeResult:
    """Minimize MPS06 Eqn. 14 over monotone p(t) with fixed endpoints and keytimes (MPS06 §3.5-3.6).

    Samples at midpoints of S equal output intervals with S ≥ ``samples_per_frame`` per source
    frame at the fastest playback; resampled (finer) when the optimum plays faster. Analytic
    gradient through the B-spline design matrices; L-BFGS-B. Cost per evaluation O(S · K).

    ``free_length``: the output length is optimized too (MPS06 Fig. 9, "length free"), starting
    from ``duration``: p(t) = P(t / k) with P on [0, duration] and k = e^ζ, ζ ∈ [−ln 2, ln 2] an
    extra parameter (its derivative by central differences); no keytimes then.

    ``samples_per_frame``, ``knots_per_second`` (``SplineParams``) and ``speed_max`` (``PolygonParams``)
    are required: their defaults live in those models only.
    """
    t0 = time.perf_counter()
    if free_length and keytimes:
        raise RetimeError("a free output length takes no keytimes (they fix output times)")
    out, src = check_keytimes(src_duration, duration, keytimes or [], speed_max)
    spline = TimingSpline.make(out, src, knots_per_second)
    z = np.zeros(spline.n_params + int(free_length))
    history: list[float] = []
    n_frames_src = src_duration * fps
    ratio = float((np.diff(src) / np.diff(out)).max())
    n_s = int(np.ceil(samples_per_frame * n_frames_src * max(ratio, 1.0) * 1.25 * (2 if free_length else 1)))
    bounds = [(None, None)] * spline.n_params + ([(-np.log(2), np.log(2))] if free_length else [])
    res = None
    iters = 0
    with single_threaded_blas():
        for _attempt in range(3):
            fun = objective_function(obj, spline, fps, duration, n_s, free_length=free_length)
            res = minimize(fun, z, jac=True, method="L-BFGS-B", bounds=bounds,
                           options={"maxiter": max_iter, "maxcor": 10, "ftol": 1e-10, "gtol": 1e-8})
            z = res.x
            iters += int(res.nit)
            history.append(float(res.fun))
            k = float(np.exp(z[-1])) if free_length else 1.0
            edges = np.linspace(0.0, duration, n_s + 1)
            _, pd_s, _ = spline.evaluate(z[:spline.n_params], 0.5 * (edges[1:] + edges[:-1]))
            step = pd_s.max() * duration / n_s * fps  # source frames between samples (k cancels)
            if step <= 1.0 / samples_per_frame + 1e-9:
                break
            n_s = int(np.ceil(n_s * step * samples_per_frame * 1.1))
    if free_length:
        k = float(np.exp(z[-1]))
        spline = replace(spline, out=spline.out * k, knots=[kn * k for kn in spline.knots])
        z, duration = z[:-1], duration * k
    n_out = round(duration * fps) + 1
    t = np.minimum(np.arange(n_out) / fps, duration)
    p, pd, pdd = spline.evaluate(z, t)
    return RetimeResult(spline=spline, z=z, t=t, p=p, pd=pd, pdd=pdd, objective=float(res.fun), n_samples=n_s,
                        iterations=iters, seconds=time.perf_counter() - t0, converged=bool(res.success),
                        message=str(res.message), history=history)


def objective_function(obj: BakedObjective, spline: TimingSpline, fps: float, duration: float, n_s: int,
                       free_length: bool = False) -> Callable[[np.ndarray], tuple[float, np.ndarray]]:
    """J(z) of MPS06 Eqn. 14 on ``n_s`` midpoint samples of [0, duration]: (value, gradient).

    One compiled pass over the samples (``objective_kernel``) plus O(n_params) for the
    softmax/cumsum parameterization; cost O(S · K), no Python per sample. ``free_length``: the
    last parameter ζ stretches the output by k = e^ζ (ṗ / k, p̈ / k², dt · k); dJ/dζ by central
    differences (two more passes).
    """
    edges = np.linspace(0.0, duration, n_s + 1)
    ctrl, w = spline.design(0.5 * (edges[1:] + edges[:-1]))
    dt = duration / n_s
    args = (obj.verts, obj.count, obj.inv_len2, obj.solid, obj.center, obj.theta0, obj.theta, obj.coef, obj.alpha, ctrl)

    n_ctrl = np.asarray(spline.n_ctrl, np.int64)
    n = spline.n_params

    def at(c: np.ndarray, k: float) -> tuple[float, np.ndarray]:
        wk = w if k == 1.0 else w * np.array([1.0, 1.0 / k, 1.0 / (k * k)])[:, None, None]
        return objective_kernel(*args, wk, c, float(fps), dt * k)

    def fun(z: np.ndarray) -> tuple[float, np.ndarray]:
        zz = np.asarray(z, float)
        c = _controls(zz[:n], n_ctrl, spline.src)
        if not free_length:
            val, grad = at(c, 1.0)
            return float(val), _chain(zz, grad, n_ctrl, spline.src)
        k, eps = float(np.exp(zz[n])), 1e-6
        val, grad = at(c, k)
        d = (at(c, k * np.exp(eps))[0] - at(c, k * np.exp(-eps))[0]) / (2 * eps)
        return float(val), np.concatenate([_chain(zz[:n], grad, n_ctrl, spline.src), [d]])

    return fun
