"""Joint torque limits observed over several actions (design §8, MPS06 §3.2 Eqn. 12, §4).

MPS06 §4: "Torque limits were determined by observing the joint torques over several actions."
The shipped table holds, per joint of the CMU/ASF skeleton family, a high quantile of |τ| (largest
component of the joint's 3 dofs) at the original timing of a set of subject-16 clips (walks, runs,
jumps; :data:`DERIVATION_CLIPS`, none of them the clips of MPS06's experiments) for a 70 kg body,
left and right alike, times :data:`STRENGTH_MARGIN` (:func:`observed_limits`). ``python -m bench.torque_limits`` recomputes it from the data.
Limits scale with the total body mass (torques of the same motion are linear in mass). Skeletons
of other families get the table's per-segment maximum (the joint's body segment from
:func:`motionweb.tasks.retime.dynamics.segments`); a config table overrides any joint.
"""

from __future__ import annotations

import numpy as np
from motionweb.tasks.retime.dynamics import DEFAULT_TOTAL_MASS, BodyModel, segments
from motionweb.tasks.retime.polygons import N_ROOT

#: subject-16 trials the table is observed on (MPS06's own experiments use 16_03, 16_06, 16_16)
DERIVATION_CLIPS: tuple[str, ...] = (
    "16_01", "16_02", "16_04", "16_05", "16_07", "16_09", "16_10",  # jumps
    "16_35", "16_36", "16_45", "16_46", "16_55", "16_56", "16_08",  # runs
    "16_15", "16_21", "16_22", "16_31", "16_32", "16_47", "16_58",  # walks
)
STRENGTH_MARGIN = 1.2
QUANTILE = 0.995
FLOOR_FRACTION = 0.02

#: N·m for a 70 kg body, by ASF joint name (the joint's torque acts on the body it carries)
CMU_TORQUE_LIMITS: dict[str, float] = {
    "lhipjoint": 297.8,  # peak 476.8 in 16_04
    "lfemur": 267.3,  # peak 391.8 in 16_08
    "ltibia": 192.8,  # peak 292.3 in 16_05
    "lfoot": 262.6,  # peak 235.0 in 16_35
    "ltoes": 6.0,  # peak 0.2 in 16_46
    "rhipjoint": 297.8,  # peak 516.6 in 16_04
    "rfemur": 267.3,  # peak 382.4 in 16_04
    "rtibia": 192.8,  # peak 220.3 in 16_04
    "rfoot": 262.6,  # peak 237.9 in 16_56
    "rtoes": 6.0,  # peak 0.4 in 16_46
    "lowerback": 244.7,  # peak 256.9 in 16_09
    "upperback": 156.8,  # peak 158.4 in 16_10
    "thorax": 74.2,  # peak 75.4 in 16_10
    "lowerneck": 12.9,  # peak 16.1 in 16_09
    "upperneck": 6.0,  # peak 5.5 in 16_09
    "head": 6.0,  # peak 1.7 in 16_07
    "lclavicle": 35.5,  # peak 41.2 in 16_10
    "lhumerus": 21.4,  # peak 23.1 in 16_10
    "lradius": 9.8,  # peak 10.2 in 16_10
    "lwrist": 6.0,  # peak 1.4 in 16_10
    "lhand": 6.0,  # peak 0.0 in 16_10
    "lfingers": 6.0,  # peak 0.0 in 16_10
    "lthumb": 6.0,  # peak 0.0 in 16_10
    "rclavicle": 35.5,  # peak 40.0 in 16_10
    "rhumerus": 21.4,  # peak 22.0 in 16_09
    "rradius": 9.8,  # peak 9.9 in 16_55
    "rwrist": 6.0,  # peak 1.4 in 16_10
    "rhand": 6.0,  # peak 0.1 in 16_10
    "rfingers": 6.0,  # peak 0.0 in 16_10
    "rthumb": 6.0,  # peak 0.0 in 16_10
}

#: N·m for a 70 kg body, by body segment: the largest of the table's joints in the segment (for
#: skeletons of other families)
SEGMENT_TORQUE_LIMITS: dict[str, float] = {
    "pelvis": 297.8,
    "thigh": 267.3,
    "shank": 192.8,
    "foot": 262.6,
    "torso": 244.7,
    "head_neck": 12.9,
    "shoulder": 35.5,
    "upper_arm": 21.4,
    "forearm": 9.8,
    "hand": 6.0,
}

#: the cgspeed BVH release of the CMU data names the same joints differently
BVH_ALIASES: dict[str, str] = {
    "hips": "root", "lhipjoint": "lhipjoint", "leftupleg": "lfemur", "leftleg": "ltibia", "leftfoot": "lfoot",
    "lefttoebase": "ltoes", "rhipjoint": "rhipjoint", "rightupleg": "rfemur", "rightleg": "rtibia",
    "rightfoot": "rfoot", "righttoebase": "rtoes", "lowerback": "lowerback", "spine": "upperback",
    "spine1": "thorax", "neck": "lowerneck", "neck1": "upperneck", "head": "head", "leftshoulder": "lclavicle",
    "leftarm": "lhumerus", "leftforearm": "lradius", "lefthand": "lwrist", "leftfingerbase": "lhand",
    "lefthandindex1": "lfingers", "lthumb": "lthumb", "rightshoulder": "rclavicle", "rightarm": "rhumerus",
    "rightforearm": "rradius", "righthand": "rwrist", "rightfingerbase": "rhand", "righthandindex1": "rfingers",
    "rthumb": "rthumb",
}


def joint_torques(body: BodyModel, tau: np.ndarray) -> dict[str, np.ndarray]:
    """Per joint name, (F,) the largest |component| of its torque in each frame (``tau`` (F, nv))."""
    return {body.skeleton.names[j]: np.abs(tau[:, body.joint_dofs(j)]).max(axis=1) for j in range(1, body.n_bodies)}


def observed_limits(samples: dict[str, list[np.ndarray]]) -> dict[str, float]:
    """Per joint, the :data:`QUANTILE` of its torques pooled over clips, the larger of a left/right
    pair (ASF names ``l…``/``r…``; a body is as strong on both sides), times :data:`STRENGTH_MARGIN`,
    at least :data:`FLOOR_FRACTION` of the largest. A quantile, not the peak: a few frames of a
    capture glitch that the repair misses (:mod:`.glitches`; unmended, 16_15's frozen left arm
    start gave its lowerback 5000 N·m) or of a clip end's extrapolated q' must not set a joint's strength."""
    q = {j: float(np.quantile(np.concatenate(v), QUANTILE)) for j, v in samples.items()}
    sym = {}
    for j, v in q.items():
        other = {"l": "r", "r": "l"}.get(j[:1], "") + j[1:]
        sym[j] = max(v, q.get(other, v)) if other in q else v
    top = max(sym.values(), default=0.0)
    return {j: round(max(v, FLOOR_FRACTION * top) * STRENGTH_MARGIN, 1) for j, v in sym.items()}


def segment_table(table: dict[str, float], body: BodyModel) -> dict[str, float]:
    """Per body segment of ``body``, the largest limit of the table's joints in it."""
    seg = segments(body.skeleton, body.scale, body.up_axis)
    out: dict[str, float] = {}
    for j, name in enumerate(body.skeleton.names):
        if j and name in table:
            out[seg[j]] = max(out.get(seg[j], 0.0), table[name])
    return out


def table_limits(body: BodyModel, overrides: dict[str, float] | None = None) -> tuple[np.ndarray, dict[str, str]]:
    """(nv,) symmetric limits (0 on the root rows) and, per joint, where its limit came from.

    Joints are looked up by name (ASF, or its BVH alias) in :data:`CMU_TORQUE_LIMITS`, else by
    segment in :data:`SEGMENT_TORQUE_LIMITS`, then scaled by total mass / 70 kg; ``overrides``
    (N·m, by joint name) win. Raises ValueError for an override naming no joint. O(J²).
    """
    table, by_segment = CMU_TORQUE_LIMITS, SEGMENT_TORQUE_LIMITS
    overrides = overrides or {}
    names = body.skeleton.names
    unknown = sorted(set(overrides) - set(names))
    if unknown:
        raise ValueError(f"torque_limits names {', '.join(unknown)}: not joints of the skeleton "
                         f"({', '.join(names[1:])})")
    scale = body.total_mass / DEFAULT_TOTAL_MASS
    seg = segments(body.skeleton, body.scale, body.up_axis)
    limits = np.zeros(body.nv)
    source: dict[str, str] = {}
    for j in range(1, body.n_bodies):
        name = names[j]
        key = name if name in table else BVH_ALIASES.get(name.lower(), "")
        if name in overrides:
            value, src = float(overrides[name]), "config"
        elif key in table:
            value, src = table[key] * scale, f"table {key}"
        elif seg[j] in by_segment:
            value, src = by_segment[seg[j]] * scale, f"segment {seg[j]}"
        else:
            raise ValueError(f"no torque limit for joint {name!r} (segment {seg[j]}): give retime.torque_limits")
        limits[body.joint_dofs(j)] = value
        source[name] = src
    limits[:N_ROOT] = 0.0
    return limits, source
