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
from motionweb.tasks.matchweb.bridges import find_bridges
from motionweb.tasks.matchweb.minima import as_grid, find_chains, local_minima, mask_self_band, valid_region
from motionweb.tasks.matchweb.params import MatchWebParams, bridge_cells, min_chain_extent, self_band
from motionweb.tasks.matchweb.refine import refine_web


def _values_at(grid: np.ndarray, cells: np.ndarray) -> np.ndarray:
    if len(cells) == 0:
        return np.zeros(0, np.float32)
    return np.asarray(grid[cells[:, 0], cells[:, 1]], dtype=np.float32)


def build_web_full(grid: np.ndarray, rate: float, cfg: MatchWebParams, self_pair: bool) -> MatchWeb:
    """Match web from a full grid at one rate (KG04 §3.1-3.2; design §4 steps 1-4).

    Self pairs ignore the band |i − j| ≤ ``self_band_s·rate``. Cost: O(Fa·Fb) for minima and the
    valid region, plus the bridge search (see :func:`find_bridges`); memory O(Fa·Fb).
    """
    g = as_grid(grid)
    if self_pair:
        g = mask_self_band(g, self_band(cfg, rate))
    minima = local_minima(g)
    valid = valid_region(g, minima, cfg.valid_a)
    cells, offsets = find_chains(g, minima, cfg.slope_k, min_chain_extent(cfg, rate))
    br, bcells, boff = find_bridges(g, valid, cells, offsets, cfg.slope_k, bridge_cells(cfg, rate))
    return MatchWeb(
        rate=rate, shape=g.shape, paths_cells=cells, paths_values=_values_at(g, cells), paths_offsets=offsets,
        bridges=br, bridges_cells=bcells, bridges_values=_values_at(g, bcells), bridges_offsets=boff,
        self_pair=self_pair, grid=np.asarray(grid) if cfg.keep_grids else None,
    )


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
    O(Fa·Fb·P) at the coarsest rate, 1/9 of the working-rate cost for 10 → 30 Hz) and runs
    :func:`build_web_full`; every finer level
    evaluates only the cells of the padded, upsampled chains and bridges (:func:`refine_web`).
    Per level the pair's shared vertical shift finishes the operands (O((Fa + Fb)·P)). With
    ``cfg.keep_grids`` the full grid at the working rate is also computed and kept (O(Fa·Fb)
    memory).
    """
    rates = sorted(oa_by_rate)
    if sorted(ob_by_rate) != rates or not rates:
        raise ValueError(f"clips A and B must have features at the same rates, got {sorted(oa_by_rate)} "
                         f"and {sorted(ob_by_rate)}")
    r0 = rates[0]
    grid0 = distance_grid_cells(*prepare_operands_pair(oa_by_rate[r0], ob_by_rate[r0]))
    web = build_web_full(grid0, r0, cfg.model_copy(update={"keep_grids": False}), self_pair)
    for r in rates[1:]:
        pa, pb = prepare_operands_pair(oa_by_rate[r], ob_by_rate[r])
        web = refine_web(web, pa, pb, r, cfg, self_pair)
        if cfg.keep_grids and r == rates[-1]:
            web.grid = distance_grid_prepared(pa, pb)
    if cfg.keep_grids and len(rates) == 1:
        web.grid = grid0
    return web
