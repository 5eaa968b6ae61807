"""Reader for DeepMimic motion clips and their URDF humanoid (design §2, §8).

Formats (see ``deepmimic/README.md`` of the data folder):

* ``motions/humanoid3d_*.txt``: JSON ``{"Loop": "wrap"|"none", "Frames": [[...], ...]}`` (some
  files add ``RightJoints``/``LeftJoints`` mirror tables, ignored). Each frame holds 44 numbers:
  the frame's duration (s; the time to the next frame, the last one usually 0), root position
  (3, m, Y up), root rotation (w, x, y, z), then per joint in :data:`DEEPMIMIC_JOINTS` order a
  local quaternion (w, x, y, z) for spherical joints or one angle (rad) about the URDF axis for
  the revolute knees and elbows.
* ``humanoid.urdf``: links (inertial origin, mass, inertia, collision shapes) and joints
  (``spherical``/``revolute``/``fixed``, parent, child, ``origin xyz``, ``axis``). Links joined
  by ``fixed`` joints are one rigid body (``base`` + ``root``; each elbow + its wrist).

Facts checked against the data (tests/test_deepmimic.py):

* Scale: the URDF lengths are 4× the motion's: DeepMimic loads it with ``globalScaling=0.25``.
  Scaled by :data:`URDF_SCALE` = 0.25 the stance feet of the walk rest on y ≈ 0 (sole of the
  foot box within ~1 cm of the ground), the standing height (sole to the top of the head sphere)
  is ~1.62 m and the jump's flight has a free-fall centre of mass. Masses are not scaled (kg,
  45 kg in all); the file's inertias (0.1 everywhere) are placeholders, so
  :attr:`HumanoidModel.inertias` are computed from the collision shapes as solid bodies (Bullet
  also recomputes inertia from the shapes unless told to use the file's).
* Frame: the motion's root position and rotation are in the URDF's frame (Y up); the character
  faces +X in the rest pose, right side +Z.
* Frame durations: 1/60, 1/30, 1/24 or 1/16 s, constant within a file except the roll, which has
  one double-length step (a dropped frame). fps is ``1 / duration`` rounded to the nearest
  integer when within 0.1%; a file with unequal durations is resampled to uniform times at its
  median duration (slerp, :func:`tasks.kinematics.sample_motion`), never rejected.
"""

from __future__ import annotations

import functools
import hashlib
import json
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field, replace
from pathlib import Path
from xml.parsers import expat

import numpy as np
from motionweb.store.errors import (
    EmptyMotionError,
    FrameValueError,
    MissingSectionError,
    SyntaxFormatError,
    TruncatedFileError,
    UnknownJointError,
)
from motionweb.store.kinematics import (
    forward_kinematics,
    quat_from_axis_angle,
    quat_identity,
    quat_mul,
    quat_normalize,
    quat_rotate,
    quat_to_matrix,
    sample_motion,
)
from motionweb.store.motion import Motion, Skeleton
from motionweb.store.textfile import line_of, number

#: DeepMimic's ``globalScaling`` for humanoid.urdf: metres per URDF unit.
URDF_SCALE = 0.25

#: joints of a DeepMimic frame after the root, in file order, with their value counts
DEEPMIMIC_JOINTS: tuple[tuple[str, int], ...] = (
    ("chest", 4), ("neck", 4),
    ("right_hip", 4), ("right_knee", 1), ("right_ankle", 4), ("right_shoulder", 4), ("right_elbow", 1),
    ("left_hip", 4), ("left_knee", 1), ("left_ankle", 4), ("left_shoulder", 4), ("left_elbow", 1),
)
FRAME_WIDTH = 1 + 3 + 4 + sum(n for _, n in DEEPMIMIC_JOINTS)  # 44
#: accepted frame durations (s), as for BVH frame times
FRAME_TIME_RANGE = (1e-5, 10.0)
#: norms of a stored quaternion that normalise safely
QUAT_NORM_RANGE = (1e-6, 1e6)
#: at most this many times the clip's frames after resampling unequal durations to the median
MAX_RESAMPLE = 4

ROOT_CHANNELS = ("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation")
JOINT_CHANNELS = ("Zrotation", "Xrotation", "Yrotation")


# ---- URDF ------------------------------------------------------------------------------------

def _rpy_quat(rpy: np.ndarray) -> np.ndarray:
    """URDF ``rpy``: fixed-axis roll (X), pitch (Y), yaw (Z): R = Rz(y) Ry(p) Rx(r)."""
    q = quat_identity()
    for k in range(3):
        e = np.zeros(3)
        e[k] = 1.0
        q = quat_mul(quat_from_axis_angle(e, rpy[k]), q)
    return q


@dataclass(frozen=True)
class Shape:
    """A collision shape in its link's frame (metres). ``size`` is a box's full extents."""

    kind: str  # 'sphere', 'capsule', 'cylinder', 'box'
    origin: np.ndarray  # (3,)
    rotation: np.ndarray  # (4,) quaternion from the origin rpy
    radius: float = 0.0
    length: float = 0.0  # capsule: between the cap centres; cylinder: height (along local z)
    size: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def inertia(self, mass: float) -> np.ndarray:
        """(3, 3) inertia about the shape's centre, in the link frame, of a solid of ``mass``."""
        r, h = self.radius, self.length
        if self.kind == "sphere":
            d = np.full(3, 0.4 * mass * r * r)
        elif self.kind == "box":
            x, y, z = self.size
            d = mass / 12.0 * np.array([y * y + z * z, x * x + z * z, x * x + y * y])
        elif self.kind == "cylinder":
            a = mass * (3 * r * r + h * h) / 12.0
            d = np.array([a, a, 0.5 * mass * r * r])
        elif self.kind == "capsule":  # solid cylinder plus two hemispheres, axis local z
            vc, vs = np.pi * r * r * h, 4.0 / 3.0 * np.pi * r ** 3
            mc, ms = mass * vc / (vc + vs), mass * vs / (vc + vs)
            axial = 0.5 * mc * r * r + 0.4 * ms * r * r
            trans = mc * (3 * r * r + h * h) / 12.0 + ms * (0.4 * r * r + 0.5 * h * h + 0.375 * h * r)
            d = np.array([trans, trans, axial])
        else:
            raise ValueError(f"no inertia for shape {self.kind!r}")
        rot = quat_to_matrix(self.rotation)
        return rot @ np.diag(d) @ rot.T


@dataclass(frozen=True)
class UrdfLink:
    """A URDF ``<link>`` (lengths scaled to metres). ``inertia`` is the file's, about the COM."""

    name: str
    mass: float
    com: np.ndarray  # (3,)
    com_rotation: np.ndarray  # (4,)
    inertia: np.ndarray  # (3, 3) as written (URDF units)
    shapes: tuple[Shape, ...]


@dataclass(frozen=True)
class UrdfJoint:
    """A URDF ``<joint>`` (origin scaled to metres)."""

    name: str
    type: str
    parent: str
    child: str
    origin: np.ndarray  # (3,)
    rpy: np.ndarray  # (3,)
    axis: np.ndarray  # (3,) unit
    limits: tuple[float, float] | None
    line: int | None = None


@dataclass(frozen=True, eq=False)
class HumanoidModel:
    """The articulated body of humanoid.urdf, one entry per skeleton joint (SI units).

    Attributes:
        skeleton: joints ``root`` (free) then the movable URDF joints, parents first; offsets in
            metres; end sites: head top (neck), wrists (elbows), toe tips on the sole (ankles).
        joint_types: 'free' (root), 'spherical' or 'revolute' per joint; URDF 'fixed' joints do not
            become skeleton joints: their links merge into the parent's body (``joints`` keeps them).
        axes: (J, 3) revolute axes in the joint frame (0 elsewhere).
        limits: (J, 2) revolute limits (rad), NaN where none.
        masses: (J,) kg, each joint's body including links fixed to it.
        coms: (J, 3) centre of mass in the joint frame (m).
        inertias: (J, 3, 3) about the COM, from the collision shapes as uniform solids (kg m²).
        file_inertias: (J, 3, 3) the URDF's inertia values combined the same way (placeholders).
        bodies: per joint the URDF links of its body.
        foot_boxes: ``{ankle joint name: box Shape in the ankle frame}`` for contact patches.
        links, joints: the parsed URDF, scaled.
    """

    skeleton: Skeleton
    joint_types: tuple[str, ...]
    axes: np.ndarray
    limits: np.ndarray
    masses: np.ndarray
    coms: np.ndarray
    inertias: np.ndarray
    file_inertias: np.ndarray
    bodies: tuple[tuple[str, ...], ...]
    foot_boxes: dict[str, Shape]
    links: dict[str, UrdfLink]
    joints: tuple[UrdfJoint, ...]
    scale: float = URDF_SCALE
    source: str | None = None
    content_hash: str = ""

    @property
    def total_mass(self) -> float:
        return float(self.masses.sum())

    # singular aliases, the interface tasks.retime.dynamics.humanoid_inertias reads
    @property
    def mass(self) -> np.ndarray:
        return self.masses

    @property
    def com(self) -> np.ndarray:
        return self.coms

    @property
    def inertia(self) -> np.ndarray:
        return self.inertias


#: largest magnitude of a URDF number (lengths, masses, inertias, angles): beyond it products overflow
URDF_MAX = 1e6
#: collision shapes the model computes volumes and inertias of
SHAPE_KINDS = ("sphere", "capsule", "cylinder", "box")


class _Xml:
    """A parsed XML document with the line of every element; DTDs (and so entities) refused."""

    def __init__(self, text: str, path: str | None):
        self.path = path
        self.lines: dict[int, int] = {}  # id(element) -> 1-based line of its start tag
        builder = ET.TreeBuilder()
        parser = expat.ParserCreate()

        def start(tag: str, attrs: dict[str, str]) -> None:
            el = builder.start(tag, attrs)
            self.lines[id(el)] = parser.CurrentLineNumber

        def refuse(*_args: object) -> None:
            raise SyntaxFormatError(path, parser.CurrentLineNumber, "XML document types and entities are refused")

        parser.StartElementHandler = start
        parser.EndElementHandler = builder.end
        parser.CharacterDataHandler = builder.data
        parser.StartDoctypeDeclHandler = refuse
        parser.EntityDeclHandler = refuse
        try:
            parser.Parse(text, True)
            self.root = builder.close()
        except expat.ExpatError as exc:
            raise SyntaxFormatError(path, exc.lineno, f"bad XML: {expat.ErrorString(exc.code)}") from None
        except (AssertionError, IndexError):  # the tree builder's own checks (e.g. no root element)
            raise SyntaxFormatError(path, parser.CurrentLineNumber, "bad XML: no complete root element") from None

    def line(self, el: ET.Element | None) -> int | None:
        return None if el is None else self.lines.get(id(el))

    def vec(self, el: ET.Element | None, attr: str, default: str, n: int = 3) -> np.ndarray:
        """``n`` finite numbers from attribute ``attr`` of ``el`` (``default`` when absent)."""
        text = default if el is None else el.get(attr, default)
        values = [number(t) for t in text.split()]
        if len(values) != n or any(v is None or abs(v) > URDF_MAX for v in values):
            tag = el.tag if el is not None else "?"
            raise SyntaxFormatError(self.path, self.line(el), f"{attr}={text!r} in <{tag}> must be {n} numbers "
                                    f"of magnitude at most {URDF_MAX:g}")
        return np.array(values, dtype=np.float64)

    def num(self, el: ET.Element | None, attr: str, default: float, minimum: float | None = None) -> float:
        """One finite number (``default`` when absent), at least ``minimum`` when given."""
        if el is None or el.get(attr) is None:
            return default
        v = float(self.vec(el, attr, "", 1)[0])
        if minimum is not None and v < minimum:
            raise FrameValueError(self.path, self.line(el), f"{attr}={v:g} in <{el.tag}> must be at least {minimum:g}")
        return v


def _parse_link(el: ET.Element, s: float, xml: _Xml) -> UrdfLink:
    inertial = el.find("inertial")
    origin = inertial.find("origin") if inertial is not None else None
    mass = xml.num(inertial.find("mass") if inertial is not None else None, "value", 0.0, minimum=0.0)
    ie = inertial.find("inertia") if inertial is not None else None
    get = {k: xml.num(ie, k, 0.0) for k in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")}
    inertia = np.array([[get["ixx"], get["ixy"], get["ixz"]],
                        [get["ixy"], get["iyy"], get["iyz"]],
                        [get["ixz"], get["iyz"], get["izz"]]])
    shapes = []
    for col in el.findall("collision"):
        o = col.find("origin")
        geom = col.find("geometry")
        if geom is None or len(geom) == 0:
            continue
        g = geom[0]
        if g.tag not in SHAPE_KINDS:
            raise SyntaxFormatError(xml.path, xml.line(g), f"unsupported collision shape <{g.tag}> "
                                    f"(expected {', '.join(SHAPE_KINDS)})")
        size = xml.vec(g, "size", "0 0 0") if g.tag == "box" else np.zeros(3)
        radius = xml.num(g, "radius", 0.0, minimum=0.0)
        if (radius <= 0) if g.tag != "box" else np.any(size <= 0):
            raise FrameValueError(xml.path, xml.line(g), f"<{g.tag}> needs a positive "
                                  f"{'radius' if g.tag != 'box' else 'size'}")
        shape = Shape(g.tag, s * xml.vec(o, "xyz", "0 0 0"), _rpy_quat(xml.vec(o, "rpy", "0 0 0")),
                      radius=s * radius,
                      length=s * xml.num(g, "length", 0.0, minimum=0.0), size=s * size)
        shapes.append(shape)
    return UrdfLink(el.get("name", ""), mass, s * xml.vec(origin, "xyz", "0 0 0"),
                    _rpy_quat(xml.vec(origin, "rpy", "0 0 0")), inertia, tuple(shapes))


def parse_humanoid_urdf(text: str, path: str | None = None, *, scale: float = URDF_SCALE,
                        content_hash: str = "") -> HumanoidModel:
    """Parse URDF text (see :func:`read_humanoid_urdf`)."""
    text = text.removeprefix("\ufeff").rstrip("\x00 \t\r\n")  # pybullet's humanoid.urdf ends with a NUL
    xml = _Xml(text, path)
    links = {}
    for el in xml.root.iter("link"):
        link = _parse_link(el, scale, xml)
        if link.name in links:
            raise SyntaxFormatError(path, xml.line(el), f"link {link.name!r} defined twice")
        links[link.name] = link
    joints = []
    for el in xml.root.iter("joint"):
        line = xml.line(el)
        parent, child = el.find("parent"), el.find("child")
        if parent is None or child is None:
            raise SyntaxFormatError(path, line, f"joint {el.get('name')!r} needs <parent> and <child>")
        o = el.find("origin")
        axis = xml.vec(el.find("axis"), "xyz", "1 0 0")
        norm = float(np.linalg.norm(axis))
        if not (np.isfinite(norm) and norm > 1e-9):
            raise FrameValueError(path, line, f"joint {el.get('name')!r}: axis {axis.tolist()} is not a direction")
        lim = el.find("limit")
        limits = None if lim is None else (xml.num(lim, "lower", 0.0), xml.num(lim, "upper", 0.0))
        j = UrdfJoint(el.get("name", ""), el.get("type", ""), parent.get("link", ""), child.get("link", ""),
                      scale * xml.vec(o, "xyz", "0 0 0"), xml.vec(o, "rpy", "0 0 0"), axis / norm, limits, line)
        for ln in (j.parent, j.child):
            if ln not in links:
                raise UnknownJointError(path, line, f"joint {j.name!r} names an unknown link {ln!r}")
        if j.type not in ("spherical", "revolute", "continuous", "fixed"):
            raise SyntaxFormatError(path, line, f"joint {j.name!r} has unsupported type {j.type!r}")
        if np.any(j.rpy != 0):
            raise SyntaxFormatError(path, line, f"joint {j.name!r}: a rotated joint origin (rpy) is not supported")
        joints.append(j)
    if not links:
        raise MissingSectionError(path, 1, "no <link> in the URDF")
    return _build_model(links, tuple(joints), scale, path, content_hash)


def _build_model(links: dict[str, UrdfLink], joints: tuple[UrdfJoint, ...], scale: float, path: str | None,
                 content_hash: str) -> HumanoidModel:
    children = {j.child for j in joints}
    tops = [n for n in links if n not in children]
    if len(tops) != 1:
        raise SyntaxFormatError(path, None, f"the URDF must have one root link, found {tops}")
    by_parent: dict[str, list[UrdfJoint]] = {}
    for j in joints:
        by_parent.setdefault(j.parent, []).append(j)

    # Every link belongs to the body of the nearest movable joint above it (the free root body
    # holds the top link and whatever is fixed to it); offsets are in that body's frame.
    owner: dict[str, tuple[str, np.ndarray]] = {tops[0]: ("root", np.zeros(3))}
    attach: dict[str, tuple[str, np.ndarray]] = {}  # movable joint -> (parent body, offset)
    stack = [tops[0]]
    while stack:
        link = stack.pop()
        body, at = owner[link]
        for j in by_parent.get(link, []):
            if j.child in owner:
                raise SyntaxFormatError(path, j.line, f"link {j.child!r} has two parents")
            if j.type == "fixed":
                owner[j.child] = (body, at + j.origin)
            else:
                if j.name in attach or j.name == "root":
                    raise SyntaxFormatError(path, j.line, f"movable joint name {j.name!r} is not unique")
                owner[j.child] = (j.name, np.zeros(3))
                attach[j.name] = (body, at + j.origin)
            stack.append(j.child)
    # movable joints in URDF file order, a joint only after its parent body
    movable = [j for j in joints if j.name in attach]
    names = ["root"]
    while len(names) <= len(movable):
        ready = [j for j in movable if j.name not in names and attach[j.name][0] in names]
        if not ready:
            raise SyntaxFormatError(path, None, "the URDF joints do not form a tree")
        names.append(ready[0].name)
    index = {nm: k for k, nm in enumerate(names)}
    by_name = {j.name: j for j in movable}
    parents = [-1] + [index[attach[nm][0]] for nm in names[1:]]
    offsets = [np.zeros(3)] + [attach[nm][1] for nm in names[1:]]
    types = ["free"] + ["revolute" if by_name[nm].type in ("revolute", "continuous") else "spherical"
                        for nm in names[1:]]
    axes = [np.zeros(3)] + [by_name[nm].axis if t == "revolute" else np.zeros(3)
                            for nm, t in zip(names[1:], types[1:], strict=True)]
    limits = [(np.nan, np.nan)] + [by_name[nm].limits if (t == "revolute" and by_name[nm].limits)
                                   else (np.nan, np.nan) for nm, t in zip(names[1:], types[1:], strict=True)]
    bodies: list[list[tuple[str, np.ndarray]]] = [[] for _ in names]
    for ln, (body, at) in owner.items():  # the body's own link first
        if body == "root" and ln == tops[0] or body != "root" and by_name[body].child == ln:
            bodies[index[body]].insert(0, (ln, at))
        else:
            bodies[index[body]].append((ln, at))
    n = len(names)
    masses, coms = np.zeros(n), np.zeros((n, 3))
    inertias, file_inertias = np.zeros((n, 3, 3)), np.zeros((n, 3, 3))
    end_sites: dict[int, np.ndarray] = {}
    foot_boxes: dict[str, Shape] = {}
    for k, body in enumerate(bodies):
        file_parts: list[tuple[float, np.ndarray, np.ndarray]] = []
        shape_parts: list[tuple[float, np.ndarray, np.ndarray]] = []
        for ln, o in body:
            link = links[ln]
            rot = quat_to_matrix(link.com_rotation)
            file_parts.append((link.mass, o + link.com, rot @ link.inertia @ rot.T * scale * scale))
            shape_parts.extend(_shape_parts(link, o) if link.shapes else [file_parts[-1]])
        m = sum(p[0] for p in file_parts)
        masses[k] = m
        coms[k] = sum(p[0] * p[1] for p in file_parts) / m if m > 0 else np.zeros(3)
        file_inertias[k] = _combine(file_parts, coms[k])
        inertias[k] = _combine(shape_parts, coms[k])
        end = _end_site(links, body, k, parents, foot_boxes, names[k])
        if end is not None:
            end_sites[k] = end
    skeleton = Skeleton(tuple(names), np.array(parents), np.array(offsets),
                        tuple(ROOT_CHANNELS if k == 0 else JOINT_CHANNELS for k in range(n)), end_sites)
    return HumanoidModel(skeleton, tuple(types), np.array(axes), np.array(limits, dtype=float), masses, coms,
                         inertias, file_inertias, tuple(tuple(ln for ln, _ in b) for b in bodies), foot_boxes,
                         links, joints, scale, path, content_hash)


def _shape_parts(link: UrdfLink, o: np.ndarray) -> list[tuple[float, np.ndarray, np.ndarray]]:
    """(mass, centre in the body frame, inertia about the centre) per collision shape, the link's
    mass shared by volume."""
    vols = np.array([_volume(s) for s in link.shapes])
    share = vols / vols.sum() if vols.sum() > 0 else np.full(len(vols), 1.0 / len(vols))
    return [(link.mass * w, o + s.origin, s.inertia(link.mass * w)) for s, w in zip(link.shapes, share, strict=True)]


def _combine(parts: list[tuple[float, np.ndarray, np.ndarray]], com: np.ndarray) -> np.ndarray:
    """Inertia about ``com`` of rigidly joined parts (parallel-axis theorem)."""
    total = np.zeros((3, 3))
    for m, c, inertia in parts:
        d = c - com
        total += inertia + m * (d @ d * np.eye(3) - np.outer(d, d))
    return total


def _volume(s: Shape) -> float:
    r, h = s.radius, s.length
    if s.kind == "sphere":
        return 4.0 / 3.0 * np.pi * r ** 3
    if s.kind == "box":
        return float(np.prod(s.size))
    if s.kind == "cylinder":
        return np.pi * r * r * h
    if s.kind == "capsule":
        return np.pi * r * r * h + 4.0 / 3.0 * np.pi * r ** 3
    return 0.0


def _end_site(links: dict[str, UrdfLink], body: list[tuple[str, np.ndarray]], k: int, parents: list[int],
              foot_boxes: dict[str, Shape], name: str) -> np.ndarray | None:
    """End site of a joint without movable children: a fixed child link's origin (wrist), else the
    front bottom edge of a box (toe on the sole; +X is forward, +Y up), else the top of a sphere."""
    own = links[body[0][0]]
    box = next((s for s in own.shapes if s.kind == "box"), None)
    if box is not None:
        foot_boxes[name] = box
    if k in parents:
        return None
    if len(body) > 1:
        return body[1][1]
    if box is not None:
        return box.origin + np.array([box.size[0] / 2, -box.size[1] / 2, 0.0])
    sphere = next((s for s in own.shapes if s.kind == "sphere"), None)
    if sphere is not None:
        c = sphere.origin
        n = np.linalg.norm(c)
        return c + (c / n if n > 0 else np.array([0.0, 1.0, 0.0])) * sphere.radius
    return None


def read_humanoid_urdf(path: str | Path, *, scale: float = URDF_SCALE) -> HumanoidModel:
    """Read DeepMimic's humanoid.urdf, lengths scaled by ``scale`` (0.25 → metres).

    Parsed once per (file, size, mtime, scale): every clip of a corpus shares the same URDF.
    """
    st = Path(path).stat() if Path(path).is_file() else None
    key = (str(Path(path).resolve()), st.st_size, st.st_mtime_ns) if st else (str(path), -1, -1)
    return _read_humanoid_urdf_cached(key, scale)


@functools.lru_cache(maxsize=8)
def _read_humanoid_urdf_cached(key: tuple[str, int, int], scale: float) -> HumanoidModel:
    raw = _read_bytes(key[0])
    return parse_humanoid_urdf(raw.decode("utf-8", errors="replace"), key[0], scale=scale,
                               content_hash=hashlib.sha256(raw).hexdigest())


def _read_bytes(path: str | Path) -> bytes:
    try:
        return Path(path).read_bytes()
    except OSError as exc:
        raise MissingSectionError(str(path), None, f"cannot read file: {exc.strerror}") from None


# ---- motions ---------------------------------------------------------------------------------

def default_urdf(motion_path: str | Path) -> Path:
    """``../humanoid.urdf`` beside the motions folder, or pybullet_data's ``humanoid/humanoid.urdf``."""
    p = Path(motion_path).resolve()
    for cand in (p.parent.parent / "humanoid.urdf", p.parent.parent.parent / "humanoid" / "humanoid.urdf"):
        if cand.is_file():
            return cand
    raise MissingSectionError(str(motion_path), None, f"no humanoid.urdf at {p.parent.parent}; pass urdf=")


def _frame_lines(text: str) -> list[int]:
    """1-based line of the opening bracket of every frame in the ``Frames`` list."""
    start = text.find('"Frames"')
    if start < 0:
        return []
    out, depth, line = [], 0, line_of(text, start)
    for m in re.finditer(r"\r\n|[\[\]\r\n]", text[start:]):
        c = m.group()
        if c in ("\n", "\r", "\r\n"):
            line += 1
        elif c == "[":
            depth += 1
            if depth == 2:
                out.append(line)
        else:
            depth -= 1
            if depth == 0:
                break
    return out


def parse_deepmimic(text: str, model: HumanoidModel, path: str | None = None, *, name: str | None = None,
                    content_hash: str = "") -> Motion:
    """Parse a DeepMimic clip against its humanoid (see the module notes for fps and scale)."""
    text = text.removeprefix("\ufeff")
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        err = TruncatedFileError if exc.pos >= len(text.rstrip()) else SyntaxFormatError
        raise err(path, line_of(text, exc.pos), f"bad JSON: {exc.msg}") from None
    except (RecursionError, ValueError) as exc:  # nesting deeper than the decoder's stack; huge integers
        raise SyntaxFormatError(path, None, f"bad JSON: {type(exc).__name__}: {exc}") from None
    if not isinstance(doc, dict) or "Frames" not in doc:
        raise MissingSectionError(path, 1, 'no "Frames" list')
    frames = doc["Frames"]
    if not isinstance(frames, list):
        raise SyntaxFormatError(path, _frame_lines(text)[:1] or None, '"Frames" is not a list')

    def where(k: int) -> int | None:
        lines = _frame_lines(text)
        return lines[k] if k < len(lines) else None

    if not frames:
        raise EmptyMotionError(path, line_of(text, max(text.find('"Frames"'), 0)), "the clip has zero frames")
    for k, fr in enumerate(frames):
        if not isinstance(fr, list) or len(fr) != FRAME_WIDTH:
            got = len(fr) if isinstance(fr, list) else type(fr).__name__
            raise FrameValueError(path, where(k), f"frame {k} has {got} values, expected {FRAME_WIDTH}")
        if not all(type(v) in (int, float) for v in fr):  # bool is an int to Python, not to JSON
            raise FrameValueError(path, where(k), f"frame {k} has a value that is not a number")
    try:
        data = np.array(frames, dtype=np.float64)
    except OverflowError:  # an integer beyond float range
        data = np.array([[float(v) if abs(v) < 1e308 else np.inf for v in fr] for fr in frames])
    bad = ~np.isfinite(data)
    if bad.any():
        k, c = (int(x) for x in np.argwhere(bad)[0])
        raise FrameValueError(path, where(k), f"frame {k} value {c} is not a finite number")
    durations = data[:, 0]
    lo, hi = FRAME_TIME_RANGE
    steps_ok = (durations >= lo) & (durations <= hi)
    steps_ok[-1] |= durations[-1] == 0  # the last frame's duration is usually 0
    if not steps_ok.all():
        k = int(np.flatnonzero(~steps_ok)[0])
        raise FrameValueError(path, where(k), f"frame {k} has duration {durations[k]:g} s, outside {lo:g}..{hi:g} s")

    sk = model.skeleton
    f = len(data)
    rot = quat_identity((f, sk.n_joints))
    root_q = data[:, 4:8]
    col = 8
    quats = [(0, root_q, 4)]
    for jname, width in DEEPMIMIC_JOINTS:
        try:
            j = sk.index(jname)
        except ValueError:
            raise UnknownJointError(model.source, None, f"the humanoid has no joint {jname!r}") from None
        vals = data[:, col:col + width]
        if width == 4:
            quats.append((j, vals, col))
        else:
            axis = model.axes[j] if model.joint_types[j] == "revolute" else np.array([0.0, 0.0, 1.0])
            rot[:, j] = quat_from_axis_angle(axis, vals[:, 0])
        col += width
    for j, q, c in quats:
        with np.errstate(over="ignore"):
            norm = np.linalg.norm(q, axis=1)
        bad = ~((norm > QUAT_NORM_RANGE[0]) & (norm < QUAT_NORM_RANGE[1]))
        if np.any(bad):
            k = int(np.flatnonzero(bad)[0])
            raise FrameValueError(path, where(k), f"frame {k}: quaternion at values {c}-{c + 3} has norm "
                                  f"{norm[k]:g}, it cannot be normalised")
        rot[:, j] = quat_normalize(q)

    if f > 1:
        steps = durations[:-1]
    else:
        steps = durations[:1] if durations[0] > 0 else np.array([1.0 / 30.0])
    dt = float(np.median(steps))
    fps = 1.0 / dt
    if abs(fps - round(fps)) < 1e-3 * fps:
        fps = float(round(fps))
    motion = Motion(
        skeleton=sk,
        fps=fps,
        root_positions=data[:, 1:4],
        rotations=rot,
        name=name if name is not None else (Path(path).stem if path else "motion"),
        source=path,
        content_hash=content_hash,
        unit="m",
        scale_to_m=1.0,
    )
    if f > 1 and np.ptp(steps) > 1e-3 * dt:
        times = np.concatenate([[0.0], np.cumsum(steps)])
        n = int(np.floor(times[-1] * fps + 1e-6)) + 1
        if n > MAX_RESAMPLE * f:
            k = int(np.argmax(steps))
            raise FrameValueError(path, where(k), f"frame {k} lasts {steps[k]:g} s, {steps[k] / dt:.0f} times the "
                                  f"median {dt:g} s: resampling would make {n} frames of {f}")
        idx = np.interp(np.arange(n) / fps, times, np.arange(f, dtype=np.float64))
        motion = replace(sample_motion(motion, idx), fps=fps)
    return motion


def read_deepmimic(path: str | Path, urdf: str | Path | HumanoidModel | None = None) -> Motion:
    """Read a DeepMimic clip (metres, Y up); ``urdf`` defaults to :func:`default_urdf`."""
    model = urdf if isinstance(urdf, HumanoidModel) else read_humanoid_urdf(urdf or default_urdf(path))
    raw = _read_bytes(path)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise SyntaxFormatError(str(path), raw.count(b"\n", 0, exc.start) + 1, "not UTF-8 text (expected JSON)") from None
    return parse_deepmimic(text, model, str(path), content_hash=hashlib.sha256(raw).hexdigest())


# ---- derived quantities ----------------------------------------------------------------------

def centre_of_mass(model: HumanoidModel, motion: Motion) -> np.ndarray:
    """(F, 3) whole-body centre of mass (m) from the per-joint masses and COM offsets."""
    pos, rot = forward_kinematics(motion)
    c = pos + quat_rotate(rot, model.coms[None])
    return np.einsum("fjk,j->fk", c, model.masses) / model.total_mass


def foot_corners(model: HumanoidModel, motion: Motion) -> dict[str, np.ndarray]:
    """``{ankle joint: (F, 4, 3)}`` the sole corners of each foot box (heel-out, heel-in, toe-in,
    toe-out order is not implied; corners are (±x, -y, ±z) of the box), in metres."""
    pos, rot = forward_kinematics(motion)
    out = {}
    for name, box in model.foot_boxes.items():
        j = motion.skeleton.index(name)
        hx, hy, hz = box.size / 2
        local = np.array([[sx * hx, -hy, sz * hz] for sx in (-1, 1) for sz in (-1, 1)])
        local = box.origin + quat_rotate(box.rotation, local)
        out[name] = pos[:, j, None] + quat_rotate(rot[:, j, None], local[None])
    return out
