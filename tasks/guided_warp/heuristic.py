"""The coarse-to-fine heuristic: solve at 1/rate, then search a band around that solution at full rate (HDP07 §3.3)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from motionweb.tasks.guided_warp.paths import feasible_windows, fixed_length_path
from motionweb.tasks.guided_warp.reduction import Reduction


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
