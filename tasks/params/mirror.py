"""The parameters of mirroring (design §11): the stage's model, its defaults in one
place. Imports only pydantic, so the run config (``flows/config.py``) loads without the stage's
compiled kernels and libraries; the stage imports its model from here."""

from __future__ import annotations

from typing import Literal

from motionweb.store.params import Params
from pydantic import Field


class MirrorParams(Params):
    """Mirroring (design "Exports")."""

    #: extra left/right joint pairs {joint: its partner}, added to and overriding the pairs found
    #: by name (a joint mapped to itself is left unpaired)
    pairs: dict[str, str] = Field(default_factory=dict)
    #: normal of the mirror plane; auto = the axis along which paired joints lie furthest apart
    #: in the rest pose
    axis: Literal["auto", "x", "y", "z"] = "auto"
