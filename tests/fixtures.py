"""Small motions and skeletons shared by the tests (imported by module name: ``from fixtures import ...``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from motionweb.store.deepmimic import DEEPMIMIC_JOINTS
from motionweb.store.kinematics import quat_from_axis_angle, quat_from_euler
from motionweb.store.motion import Motion, Skeleton

ROT_CH = ("Zrotation", "Xrotation", "Yrotation")
G = 9.81
THIGH = SHANK = 0.45


def tiny_motion(frames: int, fps: float, names: tuple[str, ...] = ("hips", "knee")) -> Motion:
    sk = Skeleton(
        names=names,
        parents=np.arange(len(names)) - 1,
        offsets=np.tile([0.0, -0.4, 0.0], (len(names), 1)),
        channels=(("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation"),)
        + (("Zrotation", "Xrotation", "Yrotation"),) * (len(names) - 1),
    )
    rot = np.zeros((frames, len(names), 4))
    rot[..., 0] = 1.0
    root = np.zeros((frames, 3))
    root[:, 2] = np.linspace(0, 1, frames)
    return Motion(skeleton=sk, fps=fps, root_positions=root, rotations=rot)


def small_skeleton(unit: str = "m") -> Skeleton:
    """A 9-joint body (hips, spine, head, two legs with knees, two arms), offsets in ``unit`` (m or cm)."""
    k = {"m": 1.0, "cm": 100.0}[unit]
    names = ("hips", "spine", "head", "lleg", "lknee", "rleg", "rknee", "larm", "rarm")
    parents = np.array([-1, 0, 1, 0, 3, 0, 5, 1, 1])
    offs = k * np.array([[0, 0, 0], [0, .3, 0], [0, .3, 0], [.1, 0, 0], [0, -.45, 0], [-.1, 0, 0], [0, -.45, 0],
                         [.2, .25, 0], [-.2, .25, 0]])
    ch = (("Xposition", "Yposition", "Zposition", *ROT_CH),) + (ROT_CH,) * 8
    return Skeleton(names, parents, offs, ch)


def wiggle(n: int, fps: float, seed: int, unit: str = "m") -> Motion:
    """(n frames) random smooth joint rotations and a root wandering forward at ~1 m/s, on
    :func:`small_skeleton` in ``unit``."""
    rng = np.random.default_rng(seed)
    sk = small_skeleton(unit)
    t = np.arange(n) / fps
    ang = np.zeros((n, sk.n_joints, 3))
    for j in range(sk.n_joints):
        for a in range(3):
            for _ in range(3):
                ang[:, j, a] += rng.uniform(2, 13) * np.sin(2 * np.pi * rng.uniform(0.1, 1.2) * t + rng.uniform(0, 6))
    yaw = np.cumsum(rng.normal(0, 0.3, n)) / fps * 20
    ang[:, 0, 2] += yaw
    root = np.stack([np.cumsum(np.sin(np.deg2rad(yaw))) / fps, np.full(n, 0.95),
                     np.cumsum(np.cos(np.deg2rad(yaw))) / fps], axis=1)
    root *= {"m": 1.0, "cm": 100.0}[unit]
    return Motion(sk, fps, root, quat_from_euler(ang, "ZXY"), name=f"wiggle{seed}", unit=unit)


def jumper_skeleton() -> Skeleton:
    """Pelvis, chest and two 3-joint legs (hip, knee, ankle with a toe end site), metres, Y up."""
    names = ("pelvis", "chest", "l_hip", "l_knee", "l_ankle", "r_hip", "r_knee", "r_ankle")
    parents = np.array([-1, 0, 0, 2, 3, 0, 5, 6])
    offsets = np.array([[0, 0, 0], [0, 0.3, 0], [0.1, -0.05, 0], [0, -THIGH, 0], [0, -SHANK, 0],
                        [-0.1, -0.05, 0], [0, -THIGH, 0], [0, -SHANK, 0]], dtype=float)
    rot = ("Zrotation", "Xrotation", "Yrotation")
    channels = (("Xposition", "Yposition", "Zposition") + rot,) + (rot,) * 7
    ends = {1: np.array([0, 0.4, 0.0]), 4: np.array([0, -0.05, 0.15]), 7: np.array([0, -0.05, 0.15])}
    return Skeleton(names, parents, offsets, channels, ends)


def hermite(y0: float, v0: float, y1: float, v1: float, T: float, t: np.ndarray) -> np.ndarray:
    s = t / T
    h00, h10 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s
    h01, h11 = -2 * s**3 + 3 * s**2, s**3 - s**2
    return h00 * y0 + h10 * T * v0 + h01 * y1 + h11 * T * v1


def synthetic_jump(fps: float = 40.0, g: float = G, v0: float = 2.0, stand: float = 0.4, bend: float = 0.4
                   ) -> tuple[Motion, tuple[float, float]]:
    """An in-place jump whose flight is exactly ballistic under gravity ``g`` (pose frozen in flight).

    Returns the motion and the flight interval (take-off, landing) in seconds.
    """
    y_stand, y_low, y_off = 0.95, 0.75, 0.98
    phases = [stand, bend, 0.3, 2 * v0 / g, 0.3, bend, stand]
    ends = np.cumsum(phases)
    n = int(np.floor(ends[-1] * fps)) + 1
    t = np.arange(n) / fps
    y = np.empty(n)
    for i, ti in enumerate(t):
        k = int(np.searchsorted(ends, ti, side="right"))
        k = min(k, len(phases) - 1)
        s = ti - (ends[k - 1] if k else 0.0)
        y[i] = [lambda s: y_stand,
                lambda s: hermite(y_stand, 0, y_low, 0, phases[1], s),
                lambda s: hermite(y_low, 0, y_off, v0, phases[2], s),
                lambda s: y_off + v0 * s - 0.5 * g * s * s,
                lambda s: hermite(y_off, -v0, y_low, 0, phases[4], s),
                lambda s: hermite(y_low, 0, y_stand, 0, phases[5], s),
                lambda s: y_stand][k](s)
    takeoff, landing = ends[2], ends[3]
    # legs: ankle 0.05 above the ground under the hip; frozen at the take-off pose in flight
    d = np.where((t > takeoff) & (t < landing), y_off, y) - 0.05 - 0.05
    d = np.minimum(d, THIGH + SHANK - 1e-6)
    knee = np.pi - np.arccos((THIGH**2 + SHANK**2 - d**2) / (2 * THIGH * SHANK))
    hip = knee / 2
    x = np.array([1.0, 0.0, 0.0])
    rot = np.zeros((n, 8, 4))
    rot[..., 0] = 1.0
    for base in (2, 5):
        rot[:, base] = quat_from_axis_angle(x, -hip)
        rot[:, base + 1] = quat_from_axis_angle(x, knee)
        rot[:, base + 2] = quat_from_axis_angle(x, -hip)
    rot[:, 1] = quat_from_axis_angle(x, 0.1 * np.sin(t))  # a little chest sway
    root = np.zeros((n, 3))
    root[:, 1] = y
    motion = Motion(jumper_skeleton(), fps, root, rot, name="synthetic_jump", unit="m")
    return motion, (float(takeoff), float(landing))


def ragged_web(rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Flat arrays of a web with three paths of different lengths (values + offsets)."""
    lengths = [5, 0, 12]
    offsets = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
    n = int(offsets[-1])
    return {
        "paths_cells": rng.integers(0, 100, size=(n, 2)).astype(np.int32),
        "paths_values": rng.random(n).astype(np.float32),
        "paths_offsets": offsets,
        "bridges": np.zeros((0, 4), np.int32),
        "shape": np.array([100, 80], np.int64),
        "rate": np.array([30.0]),
    }


# ---- a hand-made DeepMimic humanoid (own numbers, URDF units = 4 x metres) ----------------------

#  joint, type, parent link, origin, link mass, link com, collision
HUMANOID_BODY = [
    ("chest", "spherical", "root", "0 1 0", 10.0, "0 0.4 0", '<sphere radius="0.4"/>'),
    ("neck", "spherical", "chest", "0 0.8 0", 2.0, "0 0.6 0", '<sphere radius="0.4"/>'),
    ("right_hip", "spherical", "root", "0 0 0.4", 4.0, "0 -0.8 0", '<capsule length="1.2" radius="0.2"/>'),
    ("right_knee", "revolute", "right_hip", "0 -1.6 0", 3.0, "0 -0.8 0", '<capsule length="1.2" radius="0.2"/>'),
    ("right_ankle", "spherical", "right_knee", "0 -1.6 0", 1.0, "0.2 -0.1 0", '<box size="0.8 0.2 0.4"/>'),
    ("right_shoulder", "spherical", "chest", "0 0.8 0.8", 1.5, "0 -0.5 0", '<sphere radius="0.2"/>'),
    ("right_elbow", "revolute", "right_shoulder", "0 -1 0", 1.0, "0 -0.5 0", '<sphere radius="0.2"/>'),
    ("right_wrist", "fixed", "right_elbow", "0 -1 0", 0.5, "0 0 0", '<sphere radius="0.2"/>'),
]
HUMANOID_BODY += [(r[0].replace("right", "left"), r[1], r[2].replace("right", "left"),
           r[3].replace(" 0.4", " -0.4").replace(" 0.8 0.8", " 0.8 -0.8"), *r[4:]) for r in HUMANOID_BODY[2:]]
ROOT_MASS, BASE_MASS = 6.0, 0.001


def handmade_urdf_text() -> str:
    def link(name: str, mass: float, com: str, geom: str) -> str:
        rpy = "-1.570796 0 0" if "capsule" in geom else "0 0 0"
        return (f'  <link name="{name}">\n    <inertial>\n      <origin rpy="0 0 0" xyz="{com}"/>\n'
                f'      <mass value="{mass}"/>\n'
                f'      <inertia ixx="0.2" ixy="0" ixz="0" iyy="0.2" iyz="0" izz="0.2"/>\n    </inertial>\n'
                f'    <collision>\n      <origin rpy="{rpy}" xyz="{com}"/>\n'
                f'      <geometry>{geom}</geometry>\n    </collision>\n  </link>\n')

    out = ['<robot name="handmade">\n',
           f'  <link name="base"><inertial><mass value="{BASE_MASS}"/></inertial></link>\n',
           link("root", ROOT_MASS, "0 0.2 0", '<sphere radius="0.3"/>'),
           ('  <joint name="root" type="fixed"><parent link="base"/><child link="root"/>'
            '<origin rpy="0 0 0" xyz="0 0 0"/></joint>\n')]
    for name, kind, parent, origin, mass, com, geom in HUMANOID_BODY:
        out.append(link(name, mass, com, geom))
        axis = '<axis xyz="0 0 1"/><limit lower="-3" upper="0"/>' if kind == "revolute" else ""
        out.append(f'  <joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{name}"/>'
                   f'<origin rpy="0 0 0" xyz="{origin}"/>{axis}</joint>\n')
    out.append("</robot>\n\x00")  # pybullet's file ends with a NUL byte too
    return "".join(out)


def deepmimic_frame(duration: float = 1 / 30, root=(0.0, 0.9, 0.0), root_q=(1.0, 0, 0, 0), **angles: float) -> list[float]:
    """A frame with identity joints except revolute ``angles`` (rad) by joint name."""
    out = [duration, *root, *root_q]
    for name, width in DEEPMIMIC_JOINTS:
        out += [angles.get(name, 0.0)] if width == 1 else [1.0, 0.0, 0.0, 0.0]
    return out


# ---- a hand-written two-bone ASF/AMC pair ----------------------------------------------------------

CHAIN_ASF = """\
# a two-bone arm, hand written for the tests
:version 1.10
:name arm
:units
  mass 1.0
  length 0.5
  angle deg
:documentation
  upper points along +X with its axis turned 90 degrees about Z,
  lower points along +Y.
:root
  order TX TY TZ RX RY RZ
  axis XYZ
  position 0 0 0
  orientation 0 0 0
:bonedata
  begin
    id 1
    name upper
    direction 1 0 0
    length 2
    axis 0 0 90 XYZ
    dof rx ry rz
    limits (-180.0 180.0)
           (-180.0 180.0)
           (-180.0 180.0)
  end
  begin
    id 2
    name lower
    direction 0 1 0
    length 3
    axis 0 0 0 XYZ
    dof rx
    limits (-10.0 170.0)
  end
:hierarchy
  begin
    root upper
    upper lower
  end
"""

CHAIN_AMC = """\
# hand written
:FULLY-SPECIFIED
:DEGREES
1
root 1 2 3 0 0 0
upper 90 0 0
lower 90
2
root 1 2 3 0 0 0
upper 0 0 90
lower 0
"""


def lowest_root(examples, weights: np.ndarray) -> np.ndarray:
    """A custom parameter function (imported by path in the tests): the blend's lowest root height."""
    from motionweb.tasks.blend import blend_path

    pos, _ = blend_path(examples, weights)
    return pos[..., 1].min(axis=1)[:, None]


def tiny_index_config(tmp_path: Path) -> Path:
    """``tmp_path / "c.yaml"``: a config indexing three 10 s :func:`wiggle` walks with one Dask process
    worker (a CLI run that starts Prefect's server and a worker process, for the exit tests)."""
    import yaml
    from motionweb.store.bvh import write_bvh

    corpus = tmp_path / "corpus" / "walk"
    corpus.mkdir(parents=True)
    for k in range(3):
        write_bvh(wiggle(300, 30.0, seed=k), corpus / f"w{k}.bvh")
    cfg = {"corpus": {"path": str(tmp_path / "corpus"), "length_unit": "m"}, "store": {"path": str(tmp_path / "s")},
           "dask": {"processes": True, "n_workers": 1}, "output": str(tmp_path / "out")}
    (tmp_path / "c.yaml").write_text(yaml.safe_dump(cfg))
    return tmp_path / "c.yaml"
