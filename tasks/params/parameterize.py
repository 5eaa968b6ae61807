"""The parameters of motion-space sampling and interpolation (KG04 §4.2-4.3): the stage's model, its defaults in one
place. Imports only pydantic, so the run config (``flows/config.py``) loads without the stage's
compiled kernels and libraries; the stage imports its model from here."""

from __future__ import annotations

from typing import Literal

from motionweb.store.params import Params


class ParameterizeParams(Params):
    """Sampling and interpolation of a motion space (KG04 §4.2–4.3)."""

    #: random weight samples drawn (KG04 §4.4: a thousand)
    samples: int = 1000
    #: bounding box growth about its centre (KG04 §4.2: 20%)
    grow: float = 0.2
    #: δ of Eq. (1): weights in [−δ, 1 + δ]
    extrapolation: float = 0.1
    #: a sample closer than this to an existing one is dropped (m; KG04: half an inch)
    min_distance: float = 0.0127
    #: nearest samples interpolated (KG04 §4.4: k = 12)
    k: int = 12
    #: redundant-example tolerance (m; KG04 §4.4: a quarter inch)
    redundancy: float = 0.00635
    #: target corrections after the k-NN weights (0 = KG04's plain interpolation): look up
    #: t' = t' + (t − f(w(t'))) and keep the best, so weights stay in the samples' hull (Eq. 1)
    refine: int = 3
    seed: int = 0
    #: how the search's matches become examples: ``web`` = KG04 §4.1 registration along the match
    #: graph; ``flight`` = keyed by take-off and landing (``tasks/flights.py``: jumps, hops);
    #: ``auto`` = flight when the query holds exactly one flight phase, else web
    registration: Literal["auto", "web", "flight"] = "auto"
