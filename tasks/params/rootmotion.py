"""The parameters of root motion on exports (design §11): the stage's model, its defaults in one
place. Imports only pydantic, so the run config (``flows/config.py``) loads without the stage's
compiled kernels and libraries; the stage imports its model from here."""

from __future__ import annotations

from typing import Literal

from motionweb.store.params import Params


class RootMotionParams(Params):
    """Root-motion extraction on exports (design "Exports")."""

    #: keep: the hips carry the travel (as read); in-place: a root joint above the hips carries it
    mode: Literal["keep", "in-place"] = "keep"
    #: name of the added root joint (``_motion`` appended while the name is taken)
    root_name: str = "root"
