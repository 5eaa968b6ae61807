"""The parameters of physics-based retiming (design §8, MPS06 §3): the stage's model, its defaults in one
place. Imports only pydantic, so the run config (``flows/config.py``) loads without the stage's
compiled kernels and libraries; the stage imports its model from here."""

from __future__ import annotations

from typing import Literal

from motionweb.store.params import Params
from pydantic import Field

#: kg, an adult (the body model's total mass by default, and the torque table's reference)
DEFAULT_TOTAL_MASS = 70.0


class RetimeParams(Params):
    """Physics-based retiming (design §8, MPS06 §3)."""

    #: segment masses: an anthropometric table given the total mass (an adult by default), or
    #: water-density cylinders (MPS06 §4; rescaled to total_mass). DeepMimic clips use their URDF.
    body_model: Literal["cylinders", "table"] = "table"
    total_mass: float | None = DEFAULT_TOTAL_MASS
    friction: float = 0.5
    #: contact detection per foot end (toe, heel): on below height_on (m above the clip's floor) and
    #: slower than speed_on (m/s), off above height_off or faster than speed_off; gaps and contacts
    #: shorter than the minimum durations (s) are closed / dropped (see contacts.ContactRule)
    contact_height_on: float = 0.04
    contact_height_off: float = 0.07
    contact_speed_on: float = 0.6
    contact_speed_off: float = 1.2
    contact_min_s: float = 0.05
    contact_gap_s: float = 0.05
    #: a foot end this close to the floor (m) is down at any speed (mocap feet skate and pivot)
    contact_height_ground: float = 0.01
    #: floor height (m, up axis); None: each clip's own floor from its lowest foot heights
    floor_height: float | None = None
    #: per clip name: its floor height (m), overriding floor_height
    floor_heights: dict[str, float] = Field(default_factory=dict)
    #: joint torque limits (MPS06 Eqn. 12): "table" — observed over several actions (limits.py,
    #: scaled by total mass), or "clip" — the clip's own peaks x torque_margin
    torque_limits_from: Literal["table", "clip"] = "table"
    #: per joint name, a limit (N·m) overriding the table
    torque_limits: dict[str, float] = Field(default_factory=dict)
    torque_margin: float = 1.5
    #: mend capture glitches (one-frame joint turns faster than glitches.GLITCH_DEG_PER_S: spikes,
    #: steps at a clip end) in the path the dynamics are computed from; the output keeps them
    repair_glitches: bool = True
    #: half-width (s) of the local quadratic fit giving q', q'' (dynamics.path_derivatives); at
    #: 120 fps ±10 frames (q'' gain halves at ~5.5 Hz), at 30 fps ±2 frames
    smoothing_s: float = 0.08
    samples_per_frame: int = 4
    #: MPS06 Eqn. 14 weights, both unit-free: α on the squared distance to the feasible polygon
    #: priced as unexplained root force in body weights, β on the mean squared torque deviation
    #: in units of the torque limits
    alpha: float = 1.0
    beta: float = 0.1
    objective: Literal["match", "minimize"] = "match"
    #: per clip name: {foot joint: [[start_s, end_s], ...]} replacing detected contacts
    contact_intervals: dict[str, dict[str, list[tuple[float, float]]]] = Field(default_factory=dict)
    #: retime clips with no ground contact as pure flight instead of failing
    allow_flight_only: bool = False
    #: box of the (p̈, ṗ²) plane the feasible polygons are clipped to (MPS06 §3.4)
    speed_max: float = 6.0
    pdd_max: float = 40.0
    #: root force (fraction of body weight) a timing may leave unexplained beyond the clip's own
    #: (MPS06 Eqn. 13's root rows): the body model and mocap are good to a few percent
    root_tolerance: float = 0.03
    #: initial sweep directions and the LP budget per frame of the polygon sweep
    directions: int = 8
    max_lps: int = 16
    #: solver of the polygon LPs: the dense warm-started simplex (tasks/retime/simplex.py, HiGHS
    #: where it reports trouble) or HiGHS throughout (the reference, ~4x slower)
    lp_solver: Literal["simplex", "highs"] = "simplex"
    #: knots of the monotone timing spline p(t) per second of output
    knots_per_second: float = 8.0
    #: the timing of a duration without keytimes: "spline" — MPS06's optimized spline (Eqn. 14,
    #: honouring the objective); "path" — built on the source frames, inside every polygon where
    #: the duration allows and leaving them on as few output frames as it can where not
    #: (path_timing.py); "auto" — the spline when it meets the target (at most 10 % of the output
    #: frames outside their polygon), else the path timing where it leaves fewer outside, except
    #: at the clip's own length, where the path timing is the original timing itself and the
    #: spline's answer to changed physics (MPS06 Figs. 10-11) is kept. Keytimes and a free length
    #: always take the spline.
    timing: Literal["auto", "spline", "path"] = "auto"
