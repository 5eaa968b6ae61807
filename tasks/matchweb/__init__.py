"""Match webs (design §4, KG04 §3.1-3.2), one module per job:

* :mod:`.params` — :class:`MatchWebParams` and the sizes derived from it (slope rule, chain
  length, bridge length, self band);
* :mod:`.minima` — 1-D minima, the valid region, chains of minima (dense grids);
* :mod:`.band` — the slope-ruled band dynamic program, shared with registration;
* :mod:`.bridges` — bridges between chains (dense grids);
* :mod:`.refine` — coarse-to-fine refinement of a web inside upsampled bands;
* :mod:`.build` — :func:`build_web_full`, :func:`build_web`, :func:`build_web_operands`.

The web itself, :class:`motionweb.store.web.MatchWeb`, lives in the store (it is persisted there).
"""

from motionweb.store.web import MatchWeb
from motionweb.tasks.matchweb.band import (
    band_backtrack,
    band_buffers,
    band_dp,
    band_index,
    best_state_avg,
    best_state_total,
    optimal_path,
)
from motionweb.tasks.matchweb.bridges import find_bridges
from motionweb.tasks.matchweb.build import build_web, build_web_full, build_web_operands
from motionweb.tasks.matchweb.minima import as_grid, find_chains, local_minima, mask_self_band, valid_region
from motionweb.tasks.matchweb.params import (
    INF,
    MatchWebParams,
    bridge_cells,
    max_run,
    min_chain_extent,
    self_band,
)
from motionweb.tasks.matchweb.refine import refine_web, upsample_band

__all__ = [
    "INF", "MatchWeb", "MatchWebParams", "as_grid", "band_backtrack", "band_buffers", "band_dp", "band_index",
    "best_state_avg", "best_state_total", "bridge_cells", "build_web", "build_web_full", "build_web_operands",
    "find_bridges", "find_chains", "local_minima", "mask_self_band", "max_run", "min_chain_extent",
    "optimal_path", "refine_web", "self_band", "upsample_band", "valid_region",
]
