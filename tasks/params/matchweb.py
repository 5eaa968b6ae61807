"""The parameters of match webs (design §4, KG04 §3.1-3.2): the stage's model, its defaults in one
place. Imports only pydantic, so the run config (``flows/config.py``) loads without the stage's
compiled kernels and libraries; the stage imports its model from here (sizes derived from it:
``tasks/matchweb/params.py``)."""

from __future__ import annotations

from motionweb.store.params import Params


class MatchWebParams(Params):
    """Match webs (design §4, KG04 §3.1-3.2)."""

    valid_a: float = 0.15
    slope_k: int = 3
    min_chain_s: float = 0.25
    bridge_max_s: float = 2.0
    self_band_s: float = 0.25
    keep_grids: bool = False
