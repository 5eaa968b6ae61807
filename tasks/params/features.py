"""The parameters of Point-cloud features (design §3, KG04 §3.1): the stage's model, its defaults in one
place. Imports only pydantic, so the run config (``flows/config.py``) loads without the stage's
compiled kernels and libraries; the stage imports its model from here."""

from __future__ import annotations

from typing import Literal

from motionweb.store.params import Params
from pydantic import Field


class FeatureParams(Params):
    """Point-cloud features (design §3)."""

    rates: list[float] = Field(default_factory=lambda: [10.0, 20.0, 30.0])
    window: int = 5
    joint_weights: dict[str, float] = Field(default_factory=dict)
    dtype: Literal["float32", "float64"] = "float32"
