"""Derive the shipped joint torque limits of the CMU/ASF skeleton family (MPS06 §4, tasks/retime/limits.py).

Per clip of ``limits.DERIVATION_CLIPS`` (subject 16 walks, runs and jumps; not MPS06's experiment
clips 16_03, 16_06, 16_16): the 70 kg table body model, the path dynamics, the detected contacts
and the original timing's joint torques from the min-Σλ contact LP (``polygons.original_forces``),
all with the default ``RetimeParams``. Per joint the largest |component| per frame,
a high quantile pooled over the clips, left and right alike, times a margin
(``limits.observed_limits``); per segment the largest joint of the segment. Prints both tables
as Python to paste into limits.py, and which clip set each joint's peak.

Run: .venv/bin/python -m bench.torque_limits
"""

from __future__ import annotations

import numpy as np
from motionweb.store.datasets import mocap_root
from motionweb.store.formats import read_motion
from motionweb.tasks.retime.contacts import contacts_for
from motionweb.tasks.retime.dynamics import body_model_for, dynamics_terms
from motionweb.tasks.retime.limits import DERIVATION_CLIPS, joint_torques, observed_limits, segment_table
from motionweb.tasks.retime.pipeline import RetimeParams, contact_rule, polygon_options
from motionweb.tasks.retime.polygons import original_forces


def main() -> None:
    opts = RetimeParams()
    samples: dict[str, list[np.ndarray]] = {}
    peaks: dict[str, tuple[float, str]] = {}
    body = None
    for name in DERIVATION_CLIPS:
        motion = read_motion(mocap_root() / "cmu" / "asf_amc" / "16" / f"{name}.amc")
        body = body_model_for(motion, kind=opts.body_model, total_mass=opts.total_mass)
        terms = dynamics_terms(body, motion, opts.smoothing_s)
        contacts = contacts_for(body, terms.q, motion.fps, mu=opts.friction, rule=contact_rule(opts, name))
        weight = body.total_mass * float(np.linalg.norm(body.default_gravity()))
        orig = original_forces(*terms.combine(body.default_gravity()), contacts, opts.torque_margin, weight,
                               polygon_options(opts))
        for joint, value in joint_torques(body, orig.tau).items():
            samples.setdefault(joint, []).append(value)
            if value.max() > peaks.get(joint, (0.0, ""))[0]:
                peaks[joint] = (float(value.max()), name)
        print(f"# {name}: {motion.n_frames} frames, contact {contacts.active.any(axis=1).mean():.0%} of frames")
    table = observed_limits(samples)
    print("CMU_TORQUE_LIMITS: dict[str, float] = {")
    for j, v in table.items():
        print(f'    "{j}": {v},  # peak {peaks[j][0]:.1f} in {peaks[j][1]}')
    print("}")
    print("SEGMENT_TORQUE_LIMITS: dict[str, float] = {")
    for s, v in segment_table(table, body).items():
        print(f'    "{s}": {v},')
    print("}")


if __name__ == "__main__":
    main()
