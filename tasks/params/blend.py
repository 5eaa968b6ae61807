"""The parameters of blending and constraint matching (design §6, KG04 §4): the stage's model, its defaults in one
place. Imports only pydantic, so the run config (``flows/config.py``) loads without the stage's
compiled kernels and libraries; the stage imports its model from here."""

from __future__ import annotations

from motionweb.store.params import Params
from pydantic import Field


class BlendParams(Params):
    """Blending and constraint matching (KG04 §4; design §6)."""

    #: ankle joint of each foot; empty = found by name (LeftFoot / lfoot / left_ankle ...)
    feet: dict[str, str] = Field(default_factory=dict)
    #: a foot is planted where its ankle is within this height (m) of its lowest point in the clip
    plant_height: float = 0.05
    #: ... and moves horizontally slower than this (m/s)
    plant_speed: float = 0.25
    #: shortest plant kept (s)
    plant_min_s: float = 0.1
    #: IK corrections ease in and out over this long before and after a plant (s)
    ease_s: float = 0.15
    #: shortest blended frame duration, as a fraction of the mean one (very negative weights)
    min_step: float = 0.1
