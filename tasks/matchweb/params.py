"""Match-web parameters and the sizes derived from them (design §4, KG04 §3.1-3.2).

Slope rule (KG04 §3.1 "at most k frames of one motion can be mapped to a single frame of the
other"): a path holds at most ``k`` cells in one row or column in a row, i.e. at most ``k − 1``
consecutive steps along one axis (``max_run = k − 1``), which keeps its slope in [1/k, k].
"""

from __future__ import annotations

import math

import numpy as np
from motionweb.tasks.params.matchweb import MatchWebParams

#: value of a blocked cell (the ignored self band, cells outside the valid region)
INF = np.inf


#: largest slope_k: :func:`tasks.matchweb.band.band_dp` stores predecessor states 0..2·(k − 1) as int8
MAX_SLOPE_K = 64


def max_run(slope_k: int) -> int:
    """Consecutive steps allowed along one axis: ``k − 1`` (k cells per row/column, KG04 §3.1)."""
    if not 1 <= slope_k <= MAX_SLOPE_K:
        raise ValueError(f"slope_k must be in 1..{MAX_SLOPE_K}, got {slope_k} (the band DP keeps its "
                         f"2·(k − 1) + 1 run states in int8 predecessors)")
    return int(slope_k) - 1


def min_chain_extent(cfg: MatchWebParams, rate: float) -> int:
    """Frames a chain must span (max of its row and column extents) to be kept (KG04: 0.25 s)."""
    return math.ceil(cfg.min_chain_s * rate - 1e-9)


def bridge_cells(cfg: MatchWebParams, rate: float) -> int:
    """Bridge Manhattan length bound L in cells: bridges satisfy Δi + Δj < L (KG04: 2 s)."""
    return max(1, math.ceil(cfg.bridge_max_s * rate - 1e-9))


def self_band(cfg: MatchWebParams, rate: float) -> int:
    """Half-width in cells of the ignored diagonal band of a self pair (|i − j| ≤ band)."""
    return math.floor(cfg.self_band_s * rate + 1e-9)
