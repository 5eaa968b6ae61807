"""The parameters of guided time warping (design §7, HDP07 §3): the stage's model, its defaults in one
place. Imports only pydantic, so the run config (``flows/config.py``) loads without the stage's
compiled kernels and libraries; the stage imports its model from here."""

from __future__ import annotations

from motionweb.store.params import Params


class WarpParams(Params):
    """Guided time warping (design §7, HDP07 §3)."""

    skip: int = 8
    neighbours: int = 3
    filter_width: int = 5
    weights: tuple[float, float, float] = (1.0, 1.0, 1.0)
    heuristic_rate: int = 8
    #: half-width (working frames) of the full-rate band around the coarse solution (--fast)
    band: int = 48
    #: moving-average width of the warp, output frames (HDP07 §3.4)
    smooth_width: int = 5
    #: average each output frame over the local compression (HDP07 §3.4)
    adaptive_smoothing: bool = True
    #: divide pose/velocity/acceleration features by the reference's RMS spread of each
    normalize: bool = True
    #: velocities include the root's travel and turning (differences in the middle frame's torso frame)
    root_motion: bool = True
