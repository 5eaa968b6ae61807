"""The parameters of physics-based retiming (design §8, MPS06 §3): the stage's model, its defaults in one
place. Imports only pydantic, so the run config (``flows/config.py``) loads without the stage's
compiled kernels and libraries; the stage imports its model from here.

:class:`RetimeParams` holds the body model and its torque limits and three groups, one per part of
MPS06 §3, which the lower-level functions take as they are (required arguments, no defaults of
their own): ``contacts`` (:class:`ContactParams`, §3.2: ``tasks/retime/contacts.py``), ``polygons``
(:class:`PolygonParams`, §3.3-3.4: ``tasks/retime/polygons.py``) and ``spline``
(:class:`SplineParams`, §3.5-3.6 and Eqn. 14: ``objective.py``, ``spline.py``, ``path_timing.py``).
A config written before the groups (flat keys: ``retime: {contact_height_on: 0.05}``) still loads:
:data:`FLAT_KEYS` maps each old key into its group.
"""

from __future__ import annotations

from typing import Any, Literal

from motionweb.store.params import Params
from pydantic import BaseModel, Field, model_validator

#: kg, an adult (the body model's total mass by default, and the torque table's reference)
DEFAULT_TOTAL_MASS = 70.0

#: MPS06 Eqn. 14's torque term: "match" the original torques, or "minimize" effort (target 0)
Objective = Literal["match", "minimize"]


class ContactParams(Params):
    """Foot contacts and their friction (MPS06 §3.2, which needs them; the paper does not say how
    they are read from mocap: ``contacts.detect_contacts``).

    A foot's two ends — toe and heel — are each in contact while low and slow, with hysteresis:
    an end touches down within ``height_on`` (m above the floor) and slower than ``speed_on``
    (m/s), and stays down while within ``height_off`` and slower than ``speed_off``. The foot is
    in contact when an end is; then gaps shorter than ``gap_s`` are closed and contacts shorter
    than ``min_s`` (s) dropped. An end within ``height_ground`` of the floor is down at any speed:
    mocap feet skate and pivot on the floor (a run's turn slides the toe at 2-4 m/s at floor
    height), and a foot on the floor can push whether or not the markers say it is still
    (swinging feet of subject 16 pass no lower than ~1.2 cm at > 2 m/s).
    """

    #: Coulomb friction coefficient of the friction pyramids at the sole's corners
    friction: float = 0.5
    height_on: float = 0.04
    height_off: float = 0.07
    speed_on: float = 0.6
    speed_off: float = 1.2
    min_s: float = 0.05
    gap_s: float = 0.05
    height_ground: float = 0.01
    #: floor height (m, up axis); None: each clip's own floor from its lowest foot heights
    floor_height: float | None = None
    #: per clip name: its floor height (m), overriding floor_height
    floor_heights: dict[str, float] = Field(default_factory=dict)
    #: per clip name: {foot joint: [[start_s, end_s], ...]} replacing detected contacts
    intervals: dict[str, dict[str, list[tuple[float, float]]]] = Field(default_factory=dict)

    def floor_of(self, clip: str | None) -> float | None:
        """The floor height of clip ``clip`` (m): its ``floor_heights`` entry, else ``floor_height``
        (None: the clip's own floor, ``contacts.clip_floor``)."""
        return self.floor_heights.get(clip or "", self.floor_height)


class PolygonParams(Params):
    """The feasible (p̈, ṗ²) polygons of every frame (MPS06 §3.3-3.4, Eqn. 13): the box they are
    clipped to, the root force a timing may leave unexplained, and the LP sweep that finds them
    (``polygons.feasible_polygons``)."""

    #: box of the (p̈, ṗ²) plane the feasible polygons are clipped to: |p̈| ≤ pdd_max (1/s², source
    #: seconds per output second squared) and ṗ ≤ speed_max (also the fastest keytime interval)
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


class SplineParams(Params):
    """The timing p(t): the objective it minimizes (MPS06 Eqn. 14, §3.5) and the monotone spline
    optimized for it (§3.6), or the path timing built on the source frames (``path_timing.py``)."""

    #: knots of the monotone timing spline p(t) per second of output
    knots_per_second: float = 8.0
    #: samples of the objective's integral per source frame (at least; more where p runs faster)
    samples_per_frame: int = 4
    #: MPS06 Eqn. 14 weights, both unit-free: α on the squared distance to the feasible polygon
    #: priced as unexplained root force in body weights, β on the mean squared torque deviation
    #: in units of the torque limits
    alpha: float = 1.0
    beta: float = 0.1
    objective: Objective = "match"
    #: the timing of a duration without keytimes: "spline" — MPS06's optimized spline (Eqn. 14,
    #: honouring the objective); "path" — built on the source frames, inside every polygon where
    #: the duration allows and leaving them on as few output frames as it can where not
    #: (path_timing.py); "auto" — the spline when it meets the target (at most 10 % of the output
    #: frames outside their polygon), else the path timing where it leaves fewer outside, except
    #: at the clip's own length, where the path timing is the original timing itself and the
    #: spline's answer to changed physics (MPS06 Figs. 10-11) is kept. Keytimes and a free length
    #: always take the spline.
    timing: Literal["auto", "spline", "path"] = "auto"


#: the flat keys of configs written before the groups: old key -> (group, its field there)
FLAT_KEYS: dict[str, tuple[str, str]] = {
    "friction": ("contacts", "friction"),
    "contact_height_on": ("contacts", "height_on"),
    "contact_height_off": ("contacts", "height_off"),
    "contact_speed_on": ("contacts", "speed_on"),
    "contact_speed_off": ("contacts", "speed_off"),
    "contact_min_s": ("contacts", "min_s"),
    "contact_gap_s": ("contacts", "gap_s"),
    "contact_height_ground": ("contacts", "height_ground"),
    "floor_height": ("contacts", "floor_height"),
    "floor_heights": ("contacts", "floor_heights"),
    "contact_intervals": ("contacts", "intervals"),
    **{k: ("polygons", k) for k in PolygonParams.model_fields},
    **{k: ("spline", k) for k in SplineParams.model_fields},
}


class RetimeParams(Params):
    """Physics-based retiming (design §8, MPS06 §3): the body model, its torque limits and the path
    dynamics' smoothing (§3.1, Eqn. 12), and the groups ``contacts`` (§3.2), ``polygons``
    (§3.3-3.4) and ``spline`` (§3.5-3.6)."""

    #: segment masses: an anthropometric table given the total mass (an adult by default), or
    #: water-density cylinders (MPS06 §4; rescaled to total_mass). DeepMimic clips use their URDF.
    body_model: Literal["cylinders", "table"] = "table"
    total_mass: float | None = DEFAULT_TOTAL_MASS
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
    #: retime clips with no ground contact as pure flight instead of failing
    allow_flight_only: bool = False
    contacts: ContactParams = Field(default_factory=ContactParams)
    polygons: PolygonParams = Field(default_factory=PolygonParams)
    spline: SplineParams = Field(default_factory=SplineParams)

    @model_validator(mode="before")
    @classmethod
    def _flat_keys(cls, data: Any) -> Any:
        """Move the flat keys of an older config (:data:`FLAT_KEYS`) into their groups; a key given
        both ways is an error naming both. Unknown keys are left for ``extra="forbid"`` to name."""
        if not isinstance(data, dict) or not FLAT_KEYS.keys() & data.keys():
            return data
        data = dict(data)
        for old in [k for k in data if k in FLAT_KEYS]:
            group, name = FLAT_KEYS[old]
            section = data.get(group) or {}
            if isinstance(section, BaseModel):
                section = section.model_dump(exclude_unset=True)
            if not isinstance(section, dict):
                data.pop(old)  # the group itself is wrong: its own validation names it
                continue
            if name in section:
                raise ValueError(f"{old} and {group}.{name} both given: keep {group}.{name}")
            data[group] = {**section, name: data.pop(old)}
        return data
