"""Joint torque limits observed over several actions (design §8, MPS06 §3.2 Eqn. 12, §4).

MPS06 §4: "Torque limits were determined by observing the joint torques over several actions."
The shipped table holds, per joint of the CMU/ASF skeleton family, the strength the most demanding
of several kinds of action asks of it: per action (:data:`DERIVATION_CLIPS`: subject-16 walks, runs
and jumps, none of them the clips of MPS06's experiments, and a kick, a boxing trial and a climb of
other subjects) a high quantile of |τ| (largest component of the joint's 3 dofs) pooled over the
action's clips at their original timing for a 70 kg body, the largest over the actions, left and
right alike, times :data:`STRENGTH_MARGIN` (:func:`observed_limits`). ``python -m bench.torque_limits``
recomputes it from the data.
Limits scale with the total body mass (torques of the same motion are linear in mass). Skeletons
of other families get the table's per-segment maximum (the joint's body segment from
:func:`motionweb.tasks.retime.dynamics.segments`); a config table overrides any joint.
"""

from __future__ import annotations

import numpy as np
from motionweb.tasks.retime.dynamics import DEFAULT_TOTAL_MASS, BodyModel, segments
from motionweb.tasks.retime.polygons import N_ROOT

#: per action, the CMU trials (``asf_amc/<subject>/<trial>.amc``) the table is observed on; MPS06's
#: own experiments use 16_03, 16_06 and 16_16, and 16_xx trials left out check the table
DERIVATION_CLIPS: dict[str, tuple[str, ...]] = {
    "jump": ("16_01", "16_02", "16_04", "16_05", "16_07", "16_09", "16_10"),
    "run": ("16_35", "16_36", "16_45", "16_46", "16_55", "16_56", "16_08"),
    "walk": ("16_15", "16_21", "16_22", "16_31", "16_32", "16_47", "16_58"),
    "kick": ("135_04",),
    "punch": ("14_02",),
    "climb": ("14_21",),
}
STRENGTH_MARGIN = 1.2
QUANTILE = 0.995
FLOOR_FRACTION = 0.02

#: N·m for a 70 kg body, by ASF joint name (the joint's torque acts on the body it carries); each
#: with the action that sets it and the largest torque seen in any clip
CMU_TORQUE_LIMITS: dict[str, float] = {
    "lhipjoint": 382.0,  # jump; peak 476.8 in 16_04
    "lfemur": 301.7,  # punch; peak 391.8 in 16_08
    "ltibia": 220.1,  # jump; peak 292.3 in 16_05
    "lfoot": 276.1,  # run; peak 235.0 in 16_35
    "ltoes": 7.6,  # floor; peak 0.3 in 135_04
    "rhipjoint": 382.0,  # jump; peak 516.6 in 16_04
    "rfemur": 301.7,  # punch; peak 382.4 in 16_04
    "rtibia": 220.1,  # jump; peak 220.3 in 16_04
    "rfoot": 276.1,  # run; peak 237.9 in 16_56
    "rtoes": 7.6,  # floor; peak 0.4 in 16_46
    "lowerback": 279.0,  # jump; peak 273.0 in 14_02
    "upperback": 179.4,  # jump; peak 167.7 in 14_02
    "thorax": 83.3,  # jump; peak 75.6 in 14_02
    "lowerneck": 17.5,  # punch; peak 19.5 in 14_02
    "upperneck": 8.2,  # punch; peak 10.0 in 14_02
    "head": 7.6,  # floor; peak 2.6 in 14_02
    "lclavicle": 62.0,  # punch; peak 59.0 in 14_02
    "lhumerus": 47.2,  # punch; peak 40.5 in 14_02
    "lradius": 20.0,  # punch; peak 15.4 in 14_02
    "lwrist": 7.6,  # floor; peak 1.6 in 14_02
    "lhand": 7.6,  # floor; peak 0.0 in 14_02
    "lfingers": 7.6,  # floor; peak 0.0 in 14_02
    "lthumb": 7.6,  # floor; peak 0.0 in 14_02
    "rclavicle": 62.0,  # punch; peak 77.7 in 14_02
    "rhumerus": 47.2,  # punch; peak 53.4 in 14_02
    "rradius": 20.0,  # punch; peak 20.5 in 14_02
    "rwrist": 7.6,  # floor; peak 2.5 in 14_02
    "rhand": 7.6,  # floor; peak 0.2 in 135_04
    "rfingers": 7.6,  # floor; peak 0.0 in 135_04
    "rthumb": 7.6,  # floor; peak 0.2 in 135_04
}

#: N·m for a 70 kg body, by body segment: the largest of the table's joints in the segment (for
#: skeletons of other families)
SEGMENT_TORQUE_LIMITS: dict[str, float] = {
    "pelvis": 382.0,
    "thigh": 301.7,
    "shank": 220.1,
    "foot": 276.1,
    "torso": 279.0,
    "head_neck": 17.5,
    "shoulder": 62.0,
    "upper_arm": 47.2,
    "forearm": 20.0,
    "hand": 7.6,
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


def observed_limits(samples: dict[str, dict[str, list[np.ndarray]]]) -> dict[str, tuple[float, str]]:
    """Per joint, its limit and the action that sets it (or "floor"), from ``samples[action][joint]``: (F,) torque
    magnitudes per clip of the action.

    Per action the :data:`QUANTILE` of the joint's torques pooled over the action's clips; the
    largest over the actions, so an action that asks little of a joint (arms in a walk) does not
    dilute what another asks (arms in boxing); the larger of a left/right pair (ASF names
    ``l…``/``r…``; a body is as strong on both sides), times :data:`STRENGTH_MARGIN`, at least
    :data:`FLOOR_FRACTION` of the largest. A quantile, not the peak: a few frames of a capture glitch
    that the repair misses (:mod:`.glitches`; unmended, 16_15's frozen left arm start gave its
    lowerback 5000 N·m) or of a clip end's extrapolated q' must not set a joint's strength.
    """
    q: dict[str, tuple[float, str]] = {}
    for action, joints in samples.items():
        for j, v in joints.items():
            value = float(np.quantile(np.concatenate(v), QUANTILE))
            if j not in q or value > q[j][0]:
                q[j] = (value, action)
    sym = {}
    for j, v in q.items():
        other = {"l": "r", "r": "l"}.get(j[:1], "") + j[1:]
        sym[j] = max(v, q[other]) if other in q else v
    top = max((v for v, _ in sym.values()), default=0.0)
    floor = FLOOR_FRACTION * top
    return {j: (round(max(v, floor) * STRENGTH_MARGIN, 1), a if v >= floor else "floor") for j, (v, a) in sym.items()}


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
