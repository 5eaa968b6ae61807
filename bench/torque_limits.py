"""Derive the shipped joint torque limits of the CMU/ASF skeleton family (MPS06 §4, tasks/retime/limits.py).

Per action of ``limits.DERIVATION_CLIPS`` (subject-16 walks, runs and jumps, not MPS06's experiment
clips 16_03, 16_06, 16_16; a kick, a boxing trial and a climb of other subjects) and per clip: the
original timing's joint torques as ``prepare`` sees them (``pipeline.observed_torques``: 70 kg
table body model, capture glitches mended, detected contacts, the min-Σλ contact LP), all with the
default ``RetimeParams``. Per joint the largest |component| per frame, a high quantile pooled over
each action's clips, the largest over the actions, left and right alike, times a margin
(``limits.observed_limits``); per segment the largest joint of the segment. Prints both tables
as Python to paste into limits.py, with the action that sets each joint and its peak.

Run: .venv/bin/python -m bench.torque_limits
"""

from __future__ import annotations

from motionweb.store.datasets import mocap_root
from motionweb.store.formats import read_motion
from motionweb.tasks.retime.dynamics import body_model_for
from motionweb.tasks.retime.limits import DERIVATION_CLIPS, observed_limits, segment_table
from motionweb.tasks.retime.pipeline import RetimeParams, observed_torques


def main() -> None:
    opts = RetimeParams()
    samples: dict[str, dict[str, list]] = {}
    peaks: dict[str, tuple[float, str]] = {}
    motion = None
    for action, names in DERIVATION_CLIPS.items():
        for name in names:
            motion = read_motion(mocap_root() / "cmu" / "asf_amc" / name.split("_")[0] / f"{name}.amc")
            for joint, value in observed_torques(motion, opts).items():
                samples.setdefault(action, {}).setdefault(joint, []).append(value)
                if value.max() > peaks.get(joint, (0.0, ""))[0]:
                    peaks[joint] = (float(value.max()), name)
            print(f"# {action} {name}: {motion.n_frames} frames")
    table = observed_limits(samples)
    print("CMU_TORQUE_LIMITS: dict[str, float] = {")
    for j, (v, action) in table.items():
        print(f'    "{j}": {v},  # {action}; peak {peaks[j][0]:.1f} in {peaks[j][1]}')
    print("}")
    print("SEGMENT_TORQUE_LIMITS: dict[str, float] = {")
    body = body_model_for(motion, kind=opts.body_model, total_mass=opts.total_mass)
    for s, v in segment_table({j: v for j, (v, _) in table.items()}, body).items():
        print(f'    "{s}": {v},')
    print("}")


if __name__ == "__main__":
    main()
