"""Match webs: chains of 1-D minima plus bridges, built coarse to fine (design §4, KG04 §3.1-3.2).

:func:`build_web_full` runs the dense pieces (:mod:`.minima`, :mod:`.bridges`) on one full grid;
:func:`build_web` / :func:`build_web_operands` build the web at the coarsest rate from a full grid,
then refine it rate by rate (:mod:`.refine`, KG04 §3.2, Fig. 8).
"""

from __future__ import annotations

import numpy as np
from motionweb.store.web import MatchWeb
from motionweb.tasks.distance import (
    ClipOperands,
    DTypeLike,
    distance_grid_cells,
    distance_grid_prepared,
    prepare_operands_pair,
)
from motionweb.tasks.matchweb.bridges import chain_bridges
from motionweb.tasks.matchweb.minima import as_grid, dense_chains, self_band_masked
from motionweb.tasks.matchweb.params import MatchWebParams, bridge_cells, max_run, min_chain_extent, self_band
from motionweb.tasks.matchweb.refine import refine_level
from numba import njit

#: a web as the levels pass it on: (path cells (N, 2) int32, their values (N,) float32, path offsets
#: (C + 1,), bridges (B, 4), bridge cells (M, 2) int32, their values (M,) float32, bridge offsets (B + 1,))
WebArrays = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]


@njit(cache=True, nogil=True)
def _values_at(g, cells):
    """(N,) float32 grid values at (N, 2) cells."""
    out = np.empty(cells.shape[0], np.float32)
    for q in range(cells.shape[0]):
        out[q] = g[cells[q, 0], cells[q, 1]]
    return out


@njit(cache=True, nogil=True)
def _coarse_level(grid, band, valid_a, mrun, min_extent, max_len):
    """:func:`build_web_full`'s web as :data:`WebArrays`, in one compiled call: the self band
    |i − j| ≤ ``band`` masked (``minima.self_band_masked``, a copy; ``band`` < 0: none), minima,
    valid region, chains and bridges (``minima.dense_chains``, ``bridges.chain_bridges``: the
    kernels without the checks of their Python wrappers, which what this passes them meets by
    construction)."""
    g = self_band_masked(grid, band) if band >= 0 else grid
    valid, cells, offsets = dense_chains(g, valid_a, mrun, min_extent)
    br, bcells, boff = chain_bridges(g, valid, cells, offsets, mrun, max_len)
    return cells, _values_at(g, cells), offsets, br, bcells, _values_at(g, bcells), boff


def coarse_level(grid: np.ndarray, rate: float, cfg: MatchWebParams, self_pair: bool) -> WebArrays:
    """The web of a full grid at one rate as :data:`WebArrays` (:func:`build_web_full`)."""
    band = self_band(cfg, rate) if self_pair else -1
    return _coarse_level(as_grid(grid), band, float(cfg.valid_a), max_run(cfg.slope_k), min_chain_extent(cfg, rate),
                         bridge_cells(cfg, rate))


def as_web(arrays: WebArrays, rate: float, shape: tuple[int, int], self_pair: bool,
           grid: np.ndarray | None = None) -> MatchWeb:
    """The :class:`MatchWeb` of :data:`WebArrays`."""
    cells, pv, offsets, br, bcells, bv, boff = arrays
    return MatchWeb(rate=rate, shape=shape, paths_cells=cells, paths_values=pv, paths_offsets=offsets, bridges=br,
                    bridges_cells=bcells, bridges_values=bv, bridges_offsets=boff, self_pair=self_pair, grid=grid)


def build_web_full(grid: np.ndarray, rate: float, cfg: MatchWebParams, self_pair: bool) -> MatchWeb:
    """Match web from a full grid at one rate (KG04 §3.1-3.2; design §4 steps 1-4).

    Self pairs ignore the band |i − j| ≤ ``self_band_s·rate``. Cost: O(Fa·Fb) for minima and the
    valid region, plus the bridge search (see ``bridges.find_bridges``); memory O(Fa·Fb).
    """
    g = as_grid(grid)
    return as_web(coarse_level(g, rate, cfg, self_pair), rate, g.shape, self_pair,
                  np.asarray(grid) if cfg.keep_grids else None)


def build_web(fa_by_rate: dict[float, np.ndarray], fb_by_rate: dict[float, np.ndarray], weights: np.ndarray,
              cfg: MatchWebParams, self_pair: bool, dtype: DTypeLike = np.float32) -> MatchWeb:
    """Match web between clips A and B, coarse to fine across the rates given (KG04 §3.2, Fig. 8).

    ``fa_by_rate[r]``: (F_r, P, 3) clouds of A at r Hz (``tasks.features.clip_features``), same
    rates for B; the highest rate is the working rate of the result. See :func:`build_web_operands`,
    which this calls after preparing both clips (O((Fa + Fb)·P) per rate).
    """
    oa = {float(r): ClipOperands.of(f, weights, dtype) for r, f in fa_by_rate.items()}
    ob = {float(r): oa[float(r)] if f is fa_by_rate.get(r) else ClipOperands.of(f, weights, dtype)
          for r, f in fb_by_rate.items()}
    return build_web_operands(oa, ob, cfg, self_pair)


def build_web_operands(oa_by_rate: dict[float, ClipOperands], ob_by_rate: dict[float, ClipOperands],
                       cfg: MatchWebParams, self_pair: bool) -> MatchWeb:
    """Match web from per-clip operands (``tasks.distance.ClipOperands``, prepared once per clip
    and rate, e.g. once per index worker; KG04 §3.2, Fig. 8).

    The coarsest level evaluates its full grid cell by cell (``distance_grid_cells``: the same
    float64 sums as the finer levels, the same bits on the CPUs bench/cpu_bytes.py compiles for;
    O(Fa·Fb·P) at the coarsest rate, 1/9 of the working-rate cost for 10 → 30 Hz) and builds its
    web (:func:`coarse_level`); every finer level evaluates only the cells of the padded,
    upsampled chains and bridges (``refine.refine_level``). Each level is one compiled call on
    the web's arrays, and the :class:`MatchWeb` is made once, at the end (issue 25: no Python
    between the kernels of a level). Per level the pair's shared vertical shift finishes the
    operands (O((Fa + Fb)·P)). With
    ``cfg.keep_grids`` the full grid at the working rate is also computed and kept (O(Fa·Fb)
    memory).
    """
    rates = sorted(oa_by_rate)
    if sorted(ob_by_rate) != rates or not rates:
        raise ValueError(f"clips A and B must have features at the same rates, got {sorted(oa_by_rate)} "
                         f"and {sorted(ob_by_rate)}")
    r0 = rates[0]
    grid0 = distance_grid_cells(*prepare_operands_pair(oa_by_rate[r0], ob_by_rate[r0]))
    arrays = coarse_level(grid0, r0, cfg, self_pair)
    prev, grid, shape = r0, grid0, grid0.shape
    for r in rates[1:]:
        pa, pb = prepare_operands_pair(oa_by_rate[r], ob_by_rate[r])
        arrays = refine_level(arrays, prev, pa, pb, r, cfg, self_pair)
        prev, shape = r, (pa.n_frames, pb.n_frames)
        if cfg.keep_grids and r == rates[-1]:
            grid = distance_grid_prepared(pa, pb)
    return as_web(arrays, prev, shape, self_pair, grid if cfg.keep_grids else None)
