"""Reader for the Acclaim ASF (skeleton) / AMC (motion) pair used by the CMU library (design §2).

Format (Acclaim Skeleton File Definition V1.10, as written by Vicon BodyBuilder for CMU):

* ASF: ``#`` comments; commas and parentheses count as white space; keyword lines start with
  ``:``. ``:units`` (``mass``, ``length`` multiplier, ``angle deg|rad``), ``:root`` (``order`` of
  the AMC root values, ``axis`` order of the pre-set ``orientation``, ``position``),
  ``:bonedata`` (``begin`` ... ``end`` blocks with ``id``, ``name``, ``direction`` (global unit
  vector), ``length``, ``axis ax ay az ORDER``, ``dof`` (any of rx ry rz tx ty tz l) and one
  ``limits (lo hi)`` pair per dof) and ``:hierarchy`` (``begin``, ``parent child ...`` lines,
  ``end``).
* AMC: optional ``:FULLY-SPECIFIED`` and ``:DEGREES``/``:RADIANS`` lines, then per frame its
  number alone on a line followed by ``bone v1 v2 ...`` lines, the values in dof order.

Conversion to the joint model of :mod:`store.motion` (the usual ASF → BVH conversion): the
joints are the root plus one joint per bone; a bone's joint sits at the end of its parent bone,
so its offset is the parent's ``direction * length`` (zero under the root), and a bone without
children gets its own end point as an End Site. Joint frames are aligned with the global axes
in the rest pose. The local rotation of a bone is ``C M C⁻¹``, with ``C`` the rotation of the
bone's ``axis`` and ``M`` the dof rotation; both are applied in their listed order about fixed
axes (``axis 10 20 30 XYZ`` is ``Rz(30) Ry(20) Rx(10)``; ``dof rx ry rz`` is ``Rz Ry Rx``). The
numbers of ``axis``/``orientation`` are the X, Y, Z angles; the order token only sets the order
of application. The root uses the same rule with ``orientation`` (order ``axis``) as ``C`` and
the rotation tokens of ``order`` as its dofs; its position is ``position`` plus the AMC TX TY TZ.

Channels are chosen so :func:`store.bvh.write_bvh` can write the result: the root gets its
translations then three rotations; a bone with any rotation dof gets three rotation channels in
the *reverse* dof order (BVH channel order composes intrinsically, ``R = R1 R2 R3``, whereas ASF
applies dofs first to last about fixed axes), completed by the missing axes, so the BVH values
equal the AMC values when ``axis`` is zero. Translation dofs (tx ty tz, and ``l`` on the parent
bone) become per-frame joint translations with position channels.

Lengths stay in the file's unit; CMU writes inches divided by ``length`` (0.45), so by default
``scale_to_m = 0.0254 / length`` and ``unit = "in/0.45"``; pass ``length_unit`` for other
libraries. Every fault raises a :class:`~store.errors.MotionFormatError` subclass naming the
file and 1-based line.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from motionweb.store.errors import (
    EmptyMotionError,
    FrameValueError,
    MissingSectionError,
    SyntaxFormatError,
    TruncatedFileError,
    UnknownChannelError,
    UnknownJointError,
)
from motionweb.store.kinematics import quat_from_axis_angle, quat_identity, quat_inv, quat_mul, quat_rotate
from motionweb.store.motion import UNIT_SCALES, Motion, Skeleton
from motionweb.store.textfile import decode, number, read_bytes, text_lines

#: the frame rate of the CMU library's AMC files (the files do not record it)
CMU_FPS = 120.0

_DOFS = ("rx", "ry", "rz", "tx", "ty", "tz", "l")
#: accepted ``:units`` mass and length multipliers
UNIT_RANGE = (1e-6, 1e6)
_AXES = "xyz"


@dataclass(frozen=True)
class AsfBone:
    """One ``:bonedata`` block. Angles in radians; lengths in the file's unit."""

    name: str
    id: int | None
    direction: np.ndarray  # (3,) unit vector in global rest coordinates
    length: float
    axis: np.ndarray  # (3,) X, Y, Z angles (rad)
    axis_order: str  # e.g. "XYZ": order of application about fixed axes
    dof: tuple[str, ...]  # subset of rx ry rz tx ty tz l, in AMC value order
    limits: np.ndarray  # (len(dof), 2) as written (angles converted to rad), ±inf where none
    line: int  # line of the block's ``begin``


@dataclass(frozen=True)
class AsfRoot:
    """The ``:root`` section."""

    order: tuple[str, ...]  # e.g. ("tx", "ty", "tz", "rx", "ry", "rz"): AMC root value order
    axis_order: str  # order of the pre-set orientation
    position: np.ndarray  # (3,)
    orientation: np.ndarray  # (3,) X, Y, Z angles (rad)


@dataclass(frozen=True, eq=False)
class AsfSkeleton:
    """An ASF file: the joint skeleton plus what the AMC reader and physics need.

    ``joint_bones[j]`` is the ASF bone animated by joint j ('root' for joint 0); ``rest_axes``
    (J, 4) the quaternions C of each joint (root: its orientation).
    """

    skeleton: Skeleton
    root: AsfRoot
    bones: dict[str, AsfBone]
    rest_axes: np.ndarray
    name: str = ""
    version: str = ""
    documentation: str = ""
    mass_unit: float = 1.0
    length_multiplier: float = 1.0
    angle_unit: str = "deg"
    unit: str | None = None
    scale_to_m: float | None = None
    source: str | None = None
    content_hash: str = ""
    hierarchy: dict[str, tuple[str, ...]] = field(default_factory=dict)


def _clean(line: str) -> str:
    return line.split("#", 1)[0].replace(",", " ").replace("(", " ").replace(")", " ")


def _float(tok: str, path: str | None, line: int, what: str) -> float:
    v = number(tok)
    if v is None:
        raise FrameValueError(path, line, f"expected a finite number for {what}, found {tok!r}")
    return v


def _floats(toks: list[str], n: int, path: str | None, line: int, what: str) -> np.ndarray:
    if len(toks) < n:
        raise SyntaxFormatError(path, line, f"{what} needs {n} numbers, found {len(toks)}")
    return np.array([_float(t, path, line, what) for t in toks[:n]])


def euler_fixed_quat(angles: np.ndarray, order: str) -> np.ndarray:
    """Quaternion of rotations about fixed axes applied in ``order`` (first letter first).

    ``angles[..., k]`` is the angle (rad) about ``order[k]``; ``"XYZ"`` gives ``Rz Ry Rx``.
    """
    angles = np.asarray(angles, dtype=np.float64)
    q = quat_identity(angles.shape[:-1])
    for k, ax in enumerate(order.lower()):
        e = np.zeros(3)
        e[_AXES.index(ax)] = 1.0
        q = quat_mul(quat_from_axis_angle(e, angles[..., k]), q)
    return q


def _axis_quat(xyz: np.ndarray, order: str) -> np.ndarray:
    """C for ``axis ax ay az ORDER``: the three numbers are the X, Y, Z angles."""
    return euler_fixed_quat(np.array([xyz[_AXES.index(a)] for a in order.lower()]), order)


class _Lines:
    """Cleaned, non-empty ASF lines with their 1-based numbers."""

    def __init__(self, text: str, path: str | None):
        self.path = path
        raw = text_lines(text.removeprefix("\ufeff"))
        self.n_lines = len(raw)
        self.items = [(toks, i + 1, s) for i, s in enumerate(raw) if (toks := _clean(s).split())]
        self.pos = 0

    def next(self, inside: str) -> tuple[list[str], int]:
        if self.pos >= len(self.items):
            raise TruncatedFileError(self.path, self.n_lines, f"file ends inside {inside}")
        toks, line, _ = self.items[self.pos]
        self.pos += 1
        return toks, line


def _parse_bone(lines: _Lines, begin_line: int, deg: bool) -> AsfBone:
    path = lines.path
    name: str | None = None
    bone_id: int | None = None
    direction = np.array([0.0, 0.0, 0.0])
    length = 0.0
    axis = np.zeros(3)
    axis_order = "XYZ"
    dof: tuple[str, ...] = ()
    limits: list[tuple[float, float]] = []
    scale = np.pi / 180.0 if deg else 1.0
    while True:
        toks, line = lines.next(f"the bone block that begins on line {begin_line}")
        key = toks[0].lower()
        if key == "end":
            break
        if key.startswith(":"):
            raise TruncatedFileError(path, line, f"bone block from line {begin_line} has no 'end' before {toks[0]}")
        if key == "id":
            if len(toks) > 1 and not (toks[1].isascii() and toks[1].isdigit()):
                raise SyntaxFormatError(path, line, f"bone id must be a whole number, found {toks[1]!r}")
            bone_id = int(toks[1]) if len(toks) > 1 else None
        elif key == "name":
            if len(toks) < 2:
                raise SyntaxFormatError(path, line, "bone 'name' without a value")
            name = toks[1]
        elif key == "direction":
            direction = _floats(toks[1:], 3, path, line, "direction")
        elif key == "length":
            length = float(_floats(toks[1:], 1, path, line, "length")[0])
            if length < 0:
                raise FrameValueError(path, line, f"bone length must not be negative, got {toks[1]}")
        elif key == "axis":
            axis = _floats(toks[1:], 3, path, line, "axis") * scale
            axis_order = toks[4].upper() if len(toks) > 4 else "XYZ"
            if sorted(axis_order) != ["X", "Y", "Z"]:
                raise SyntaxFormatError(path, line, f"bad axis order {axis_order!r}")
        elif key == "dof":
            if dof:
                raise SyntaxFormatError(path, line, "a second 'dof' line in one bone")
            if limits:
                raise SyntaxFormatError(path, line, "'dof' after 'limits'")
            d = tuple(t.lower() for t in toks[1:])
            for t in d:
                if t not in _DOFS:
                    raise UnknownChannelError(path, line, f"unknown dof {t!r} (expected {' '.join(_DOFS)})")
            if len(set(d)) != len(d):
                raise SyntaxFormatError(path, line, f"repeated dof in {' '.join(d)}")
            dof = d
        elif key == "limits":
            if not dof or limits:
                raise SyntaxFormatError(path, line, "'limits' without a 'dof' line before it" if not dof
                                        else "a second 'limits' in one bone")
            rest = toks[1:]
            while True:  # one (lo hi) pair per dof, on this line and the following ones
                if len(rest) < 2 or len(rest) % 2:
                    raise SyntaxFormatError(path, line, "limits must be (lo hi) pairs")
                for a in range(0, len(rest), 2):
                    limits.append((_float(rest[a], path, line, "limits"), _float(rest[a + 1], path, line, "limits")))
                if len(limits) > len(dof):
                    raise SyntaxFormatError(path, line, f"{len(limits)} limits for {len(dof)} dofs")
                if len(limits) == len(dof):
                    break
                toks, line = lines.next(f"the limits of the bone block from line {begin_line}")
                rest = toks
        # bodymass, cofmass and vendor extensions are ignored
    if name is None:
        raise SyntaxFormatError(path, begin_line, "bone block without a name")
    if limits and len(limits) != len(dof):
        raise SyntaxFormatError(path, begin_line, f"bone {name}: {len(limits)} limits for {len(dof)} dofs")
    norm = np.linalg.norm(direction)
    if not np.isfinite(norm) or (norm == 0 and length > 0):
        raise FrameValueError(path, begin_line, f"bone {name}: direction {direction.tolist()} is not a direction")
    if norm > 0:
        direction = direction / norm
    lim = np.full((len(dof), 2), [-np.inf, np.inf])
    if limits:
        lim[:] = np.array(limits)
        rot = np.array([d.startswith("r") for d in dof])
        lim[rot] *= scale
    return AsfBone(name, bone_id, direction, length, axis, axis_order, dof, lim, begin_line)


def parse_asf(text: str, path: str | None = None, *, length_unit: str = "in",
              content_hash: str = "") -> AsfSkeleton:
    """Parse ASF text. ``length_unit`` is the unit the ``length`` multiplier divides (CMU: in)."""
    lines = _Lines(text, path)
    version = name = documentation = ""
    mass = length_mult = 1.0
    angle = "deg"
    root: AsfRoot | None = None
    bones: dict[str, AsfBone] = {}
    hierarchy: dict[str, tuple[str, ...]] = {}
    hierarchy_lines: dict[str, int] = {}
    seen: set[str] = set()
    raw_lines = text_lines(text.removeprefix("\ufeff"))
    while lines.pos < len(lines.items):
        toks, line = lines.next("the file")
        key = toks[0].lower()
        if not key.startswith(":"):
            raise SyntaxFormatError(path, line, f"unexpected {toks[0]!r} outside a section")
        seen.add(key)
        if key == ":version":
            version = toks[1] if len(toks) > 1 else ""
        elif key == ":name":
            name = " ".join(toks[1:])
        elif key == ":units":
            while lines.pos < len(lines.items) and not lines.items[lines.pos][0][0].startswith(":"):
                toks, line = lines.next(":units")
                k = toks[0].lower()
                if len(toks) < 2:
                    raise SyntaxFormatError(path, line, f"unit {toks[0]!r} without a value")
                if k == "mass":
                    mass = _float(toks[1], path, line, "mass unit")
                    if not UNIT_RANGE[0] <= mass <= UNIT_RANGE[1]:
                        raise FrameValueError(path, line, f"mass unit {toks[1]} is outside {UNIT_RANGE}")
                elif k == "length":
                    length_mult = _float(toks[1], path, line, "length unit")
                    if not UNIT_RANGE[0] <= length_mult <= UNIT_RANGE[1]:
                        raise FrameValueError(path, line, f"length unit {toks[1]} is outside {UNIT_RANGE}")
                elif k == "angle":
                    angle = toks[1].lower()
                    if angle not in ("deg", "rad"):
                        raise SyntaxFormatError(path, line, f"angle unit must be deg or rad, found {toks[1]!r}")
        elif key == ":documentation":
            doc = []
            while lines.pos < len(lines.items) and not lines.items[lines.pos][0][0].startswith(":"):
                lines.pos += 1
                doc.append(raw_lines[lines.items[lines.pos - 1][1] - 1].strip())
            documentation = "\n".join(doc)
        elif key == ":root":
            order: tuple[str, ...] = ("tx", "ty", "tz", "rx", "ry", "rz")
            axis_order = "XYZ"
            position = np.zeros(3)
            orientation = np.zeros(3)
            while lines.pos < len(lines.items) and not lines.items[lines.pos][0][0].startswith(":"):
                toks, line = lines.next(":root")
                k = toks[0].lower()
                if k == "order":
                    order = tuple(t.lower() for t in toks[1:])
                    for t in order:
                        if t not in _DOFS[:6]:
                            raise UnknownChannelError(path, line, f"unknown root channel {t!r}")
                elif k == "axis":
                    axis_order = toks[1].upper() if len(toks) > 1 else ""
                    if sorted(axis_order) != ["X", "Y", "Z"]:
                        raise SyntaxFormatError(path, line, f"bad root axis order {axis_order!r}")
                elif k == "position":
                    position = _floats(toks[1:], 3, path, line, "root position")
                elif k == "orientation":
                    orientation = _floats(toks[1:], 3, path, line, "root orientation")
            root = AsfRoot(order, axis_order, position, orientation)
        elif key == ":bonedata":
            deg = angle == "deg"
            while lines.pos < len(lines.items) and not lines.items[lines.pos][0][0].startswith(":"):
                toks, line = lines.next(":bonedata")
                if toks[0].lower() != "begin":
                    raise SyntaxFormatError(path, line, f"expected 'begin' in :bonedata, found {toks[0]!r}")
                bone = _parse_bone(lines, line, deg)
                if bone.name in bones or bone.name == "root":
                    raise SyntaxFormatError(path, bone.line, f"bone {bone.name!r} defined twice")
                bones[bone.name] = bone
        elif key == ":hierarchy":
            start = line
            toks, line = lines.next(":hierarchy")
            if toks[0].lower() != "begin":
                raise SyntaxFormatError(path, line, f"expected 'begin' after :hierarchy, found {toks[0]!r}")
            while True:
                toks, line = lines.next(f"the :hierarchy from line {start} (no 'end')")
                if toks[0].lower() == "end":
                    break
                if toks[0].startswith(":"):
                    raise TruncatedFileError(path, line, f":hierarchy from line {start} has no 'end'")
                if "root" in toks[1:]:
                    raise SyntaxFormatError(path, line, "the root cannot be a child in :hierarchy")
                hierarchy[toks[0]] = hierarchy.get(toks[0], ()) + tuple(toks[1:])
                for child in toks[1:]:
                    hierarchy_lines[child] = line
                hierarchy_lines.setdefault(toks[0], line)
        # other keywords (e.g. :skin) are ignored
    last = lines.n_lines
    if root is None:
        raise MissingSectionError(path, last, "no :root section")
    if ":bonedata" not in seen:
        raise MissingSectionError(path, last, "no :bonedata section")
    if ":hierarchy" not in seen:
        raise MissingSectionError(path, last, "no :hierarchy section")
    if angle == "deg":
        root = AsfRoot(root.order, root.axis_order, root.position, np.deg2rad(root.orientation))
    for parent, children in hierarchy.items():
        for n in (parent, *children):
            if n != "root" and n not in bones:
                raise UnknownJointError(path, hierarchy_lines.get(n), f"hierarchy names bone {n!r} not in :bonedata")
    if base := UNIT_SCALES.get(length_unit):
        scale_to_m = base / length_mult
    else:
        raise ValueError(f"unknown length unit {length_unit!r}; expected one of {', '.join(UNIT_SCALES)}")
    unit = length_unit if length_mult == 1.0 else f"{length_unit}/{length_mult:g}"
    return _build(path, root, bones, hierarchy, version, name, documentation, mass, length_mult, angle,
                  unit, scale_to_m, content_hash)


def _build(path: str | None, root: AsfRoot, bones: dict[str, AsfBone], hierarchy: dict[str, tuple[str, ...]],
           version: str, name: str, documentation: str, mass: float, length_mult: float, angle: str,
           unit: str, scale_to_m: float, content_hash: str) -> AsfSkeleton:
    names = ["root"]
    parents = [-1]
    stack = list(reversed(hierarchy.get("root", ())))
    owner = {c: 0 for c in stack}
    while stack:  # depth first, parents before children
        b = stack.pop()
        if b in names:
            raise SyntaxFormatError(path, bones[b].line, f"bone {b!r} has two parents in :hierarchy")
        names.append(b)
        parents.append(owner[b])
        kids = hierarchy.get(b, ())
        for c in kids:
            owner[c] = len(names) - 1
        stack.extend(reversed(kids))
    for b, bone in bones.items():
        if b not in names:
            raise SyntaxFormatError(path, bone.line, f"bone {b!r} is not connected to the root by :hierarchy")
    j = len(names)
    offsets = np.zeros((j, 3))
    offsets[0] = root.position
    channels: list[tuple[str, ...]] = []
    rest = quat_identity((j,))
    rest[0] = _axis_quat(root.orientation, root.axis_order)
    for k in range(1, j):
        p = parents[k]
        if p > 0:
            pb = bones[names[p]]
            offsets[k] = pb.direction * pb.length
        rest[k] = _axis_quat(bones[names[k]].axis, bones[names[k]].axis_order)
    for k in range(j):
        dof = root.order if k == 0 else bones[names[k]].dof
        channels.append(_joint_channels(dof, k == 0 or _has_translation(k, names, parents, bones)))
    end_sites = {k: bones[names[k]].direction * bones[names[k]].length
                 for k in range(1, j) if k not in parents}
    skeleton = Skeleton(tuple(names), np.array(parents), offsets, tuple(channels), end_sites)
    return AsfSkeleton(skeleton, root, bones, rest, name, version, documentation, mass, length_mult, angle,
                       unit, scale_to_m, path, content_hash, dict(hierarchy))


def _has_translation(k: int, names: list[str], parents: list[int], bones: dict[str, AsfBone]) -> bool:
    """Whether joint k moves relative to its parent: its own t* dofs or an ``l`` dof on the parent bone."""
    own = any(d.startswith("t") for d in bones[names[k]].dof)
    p = parents[k]
    return own or (p > 0 and "l" in bones[names[p]].dof)


def _joint_channels(dof: tuple[str, ...], translated: bool) -> tuple[str, ...]:
    rot = [d[1] for d in dof if d.startswith("r")]
    out: list[str] = []
    if translated:
        pos = [d[1] for d in dof if d.startswith("t")]
        pos += [a for a in _AXES if a not in pos]
        out += [a.upper() + "position" for a in pos]
    if rot:
        order = rot[::-1] + [a for a in _AXES if a not in rot]
        out += [a.upper() + "rotation" for a in order]
    return tuple(out)


def _read_text(path: str | Path) -> tuple[str, str]:
    raw, digest = read_bytes(path)
    return decode(raw), digest


def read_asf(path: str | Path, *, length_unit: str = "in") -> AsfSkeleton:
    """Read an ASF skeleton file. See :func:`parse_asf`."""
    text, digest = _read_text(path)
    return parse_asf(text, str(path), length_unit=length_unit, content_hash=digest)


@dataclass(frozen=True)
class AmcValues:
    """The numbers of an AMC file per bone: ``values[k]`` is ``(F, len(dof_k))`` for every bone the
    file lists (bones it never lists keep their rest pose); ``degrees`` is the file's angle unit."""

    values: dict[int, np.ndarray]
    n_frames: int
    degrees: bool


def parse_amc(text: str, asf: AsfSkeleton, path: str | None = None, *, fps: float = CMU_FPS,
              name: str | None = None, content_hash: str = "") -> Motion:
    """Parse AMC text against its skeleton into a :class:`Motion` (lengths in the ASF's unit).

    A file in the layout every exporter writes (a header of ``#`` and ``:`` lines, then frames
    numbered 1, 2, ... that each list the same bones in the same order) is read in bulk by
    :func:`amc_values_regular`; anything else goes through :func:`amc_values_by_lines`, which
    accepts the same files and more and names the line of what it cannot accept. Angles are degrees
    unless the file says ``:RADIANS`` (or the ASF says ``angle rad`` and the AMC has no ``:DEGREES``).
    """
    read = amc_values_regular(text, asf) or amc_values_by_lines(text, asf, path)
    return _amc_motion(asf, read.values, read.n_frames, read.degrees, fps, path, name, content_hash)


_FRAME_LINE = re.compile(r"^[ \t]*[0-9]+[ \t]*$", re.M)


def amc_values_regular(text: str, asf: AsfSkeleton) -> AmcValues | None:
    """The values of an AMC file in the regular layout, or None when it departs from it anywhere.

    The first frame gives the layout (its bones in order and their value counts). The body must then
    be that layout repeated: every non-blank line holds exactly the layout's number of tokens
    (counted on the bytes with numpy), every bone name and frame number (1, 2, ...) sits where the
    layout puts it, and every value is a plain finite decimal. A file that passes is read exactly
    as :func:`amc_values_by_lines` reads it. Cost is linear in the file's size, with no Python
    work per line.
    """
    sk = asf.skeleton
    index = {n: k for k, n in enumerate(sk.names)}
    text = text.removeprefix("\ufeff")
    if "\r" in text:
        text = text.replace("\r\n", "\n").replace("\r", "\n")
    first = _FRAME_LINE.search(text)
    if first is None:
        return None
    degrees = asf.angle_unit == "deg"
    for line in text[:first.start()].split("\n"):
        head = line.strip().upper()
        if head in (":DEGREES", ":RADIANS"):
            degrees = head == ":DEGREES"
        elif head and not head.startswith(("#", ":")):
            return None
    body = text[first.start():]
    if not body.isascii():
        return None
    second = _FRAME_LINE.search(body, first.end() - first.start())
    bones: list[tuple[int, int]] = []
    for line in body[:second.start() if second else len(body)].split("\n")[1:]:
        toks = line.split()
        if not toks:
            continue
        k = index.get(toks[0])
        n = len(asf.root.order if k == 0 else asf.bones[toks[0]].dof) if k is not None else -1
        if k is None or n != len(toks) - 1 or any(k == b for b, _ in bones):
            return None
        bones.append((k, n))
    per_line = _tokens_per_line(body)
    layout = np.array([1] + [1 + n for _, n in bones])
    n_frames, rest = divmod(len(per_line) if per_line is not None else -1, len(layout))
    if per_line is None or rest or not np.array_equal(per_line, np.tile(layout, n_frames)):
        return None
    toks = body.split()
    width = int(layout.sum())
    heads = np.cumsum(layout) - layout
    for h, (k, _) in zip(heads[1:], bones):
        if toks[h::width].count(sk.names[k]) != n_frames:
            return None
        toks[h::width] = ["0"] * n_frames
    if _NOT_DECIMAL.search("".join(toks)):
        return None
    try:
        table = np.array(toks, dtype=np.float64).reshape(n_frames, width)
    except ValueError:  # e.g. "1e" or "1.2.3"
        return None
    numbers = toks[::width]
    if not "".join(numbers).isdigit() or np.any(np.diff(table[:, 0]) != 1) or not np.isfinite(table).all():
        return None
    return AmcValues({k: table[:, h + 1:h + 1 + n] for h, (k, n) in zip(heads[1:], bones)}, n_frames, degrees)


def _tokens_per_line(body: str) -> np.ndarray | None:
    """Number of space/tab-separated tokens on each non-blank line of ASCII text ``body``; None when
    it holds any other control character or a ``#`` (where ``str.split`` or a comment would read
    the line differently)."""
    b = np.frombuffer(body.encode("ascii"), np.uint8)
    if np.any(((b < 32) & (b != 9) & (b != 10)) | (b == 127) | (b == 35)):
        return None
    gap = (b == 32) | (b == 9) | (b == 10)
    starts = np.flatnonzero(~gap & np.concatenate([[True], gap[:-1]]))
    line = np.searchsorted(np.flatnonzero(b == 10), starts)
    counts = np.bincount(line)
    return counts[counts > 0]


def amc_values_by_lines(text: str, asf: AsfSkeleton, path: str | None = None) -> AmcValues:
    """The values of any AMC file :func:`parse_amc` accepts, read line by line.

    One pass over the lines collects each bone's value tokens (bones in any order within a frame);
    numbers are converted per bone in bulk. Raises a :class:`MotionFormatError` naming the line of
    the first thing it cannot accept.
    """
    sk = asf.skeleton
    index = {n: k for k, n in enumerate(sk.names)}
    dofs = [asf.root.order] + [asf.bones[n].dof for n in sk.names[1:]]
    deg = asf.angle_unit == "deg"
    tokens: dict[int, list[str]] = {}
    rows: dict[int, list[int]] = {}  # per joint, the line of each of its frame lines
    frame_lines: list[int] = []
    frame_number = -1
    present: set[int] = set()
    required: set[int] | None = None
    raw = text_lines(text.removeprefix("\ufeff"))
    for i, line in enumerate(raw):
        toks = line.split("#", 1)[0].split()
        if not toks:
            continue
        head = toks[0]
        if head.startswith(":"):
            u = head.upper()
            if u == ":DEGREES":
                deg = True
            elif u == ":RADIANS":
                deg = False
            continue
        if len(toks) == 1 and head not in index:  # a frame number
            if not (head.isascii() and head.isdigit()):
                raise SyntaxFormatError(path, i + 1, f"expected a frame number, found {head!r}")
            if frame_lines and int(head) != frame_number + 1:
                raise SyntaxFormatError(path, i + 1, f"frame {head} follows frame {frame_number}")
            if frame_lines:
                required = _check_frame(required, present, frame_lines[-1], sk.names, path)
            frame_number = int(head)
            frame_lines.append(i + 1)
            present = set()
            continue
        if not frame_lines:
            raise SyntaxFormatError(path, i + 1, f"{head!r} before the first frame number")
        k = index.get(head)
        if k is None:
            raise UnknownJointError(path, i + 1, f"bone {head!r} is not in the skeleton {asf.source or ''}".rstrip())
        n = len(dofs[k])
        if len(toks) - 1 != n:
            if len(toks) - 1 < n and not any(r.strip() for r in raw[i + 1:]):
                raise TruncatedFileError(path, i + 1, f"file ends inside the values of bone {head!r}")
            raise FrameValueError(path, i + 1, f"bone {head!r} has {len(toks) - 1} values, expected {n}")
        if k in present:
            raise FrameValueError(path, i + 1, f"bone {head!r} appears twice in frame {frame_number}")
        if required is not None and k not in required:
            raise FrameValueError(path, i + 1, f"bone {head!r} is in frame {frame_number} but not in the first")
        present.add(k)
        tokens.setdefault(k, []).extend(toks[1:])
        rows.setdefault(k, []).append(i + 1)
    if not frame_lines:
        raise EmptyMotionError(path, max(len(raw), 1), "the file has no frames")
    missing = (required or set(present)) - present
    if missing:
        raise TruncatedFileError(
            path, len(raw),
            f"file ends inside frame {frame_number}: no {', '.join(sk.names[m] for m in sorted(missing))}")
    n_frames = len(frame_lines)
    values: dict[int, np.ndarray] = {}
    bad_line = None
    for k, toks in tokens.items():
        arr = None
        if not _NOT_DECIMAL.search("".join(toks)):
            try:
                arr = np.array(toks, dtype=np.float64).reshape(n_frames, -1)
            except ValueError:
                arr = None
        if arr is None or not np.isfinite(arr).all():
            r = next((r for r, line_no in enumerate(rows[k]) if not _numeric(raw[line_no - 1])), 0)
            bad_line = min(bad_line or rows[k][r], rows[k][r])
            continue
        values[k] = arr
    if bad_line is not None:
        raise FrameValueError(path, bad_line, f"non-numeric or non-finite value in {raw[bad_line - 1].strip()!r}")
    return AmcValues(values, n_frames, deg)


#: a character no plain decimal number has (letters of nan/inf, ``_``, ...)
_NOT_DECIMAL = re.compile(r"[^0-9eE+\-.]")


def _numeric(line: str) -> bool:
    return all(number(t) is not None for t in line.split("#", 1)[0].split()[1:])


def _check_frame(required: set[int] | None, present: set[int], frame_line: int, names: tuple[str, ...],
                 path: str | None) -> set[int]:
    """Every frame must list the bones of the first frame."""
    if required is None:
        return set(present)
    missing = required - present
    if missing:
        raise FrameValueError(path, frame_line,
                              f"frame misses {', '.join(names[m] for m in sorted(missing))}")
    return required


def _amc_motion(asf: AsfSkeleton, values: dict[int, np.ndarray], n_frames: int, deg: bool, fps: float,
                path: str | None, name: str | None, content_hash: str) -> Motion:
    sk = asf.skeleton
    j = sk.n_joints
    rotations = quat_identity((n_frames, j))
    root = np.broadcast_to(asf.root.position, (n_frames, 3)).copy()
    translations: dict[int, np.ndarray] = {}
    ang = np.pi / 180.0 if deg else 1.0
    lengths: dict[int, np.ndarray] = {}
    for k in range(j):
        dof = asf.root.order if k == 0 else asf.bones[sk.names[k]].dof
        v = values.get(k, np.zeros((n_frames, len(dof))))
        rot = [i for i, d in enumerate(dof) if d.startswith("r")]
        c = asf.rest_axes[k]
        if rot:
            m = euler_fixed_quat(v[:, rot] * ang, "".join(dof[i][1] for i in rot))
            rotations[:, k] = quat_mul(quat_mul(c, m), quat_inv(c))
        tr = [i for i, d in enumerate(dof) if d.startswith("t")]
        if tr:
            t = np.zeros((n_frames, 3))
            for i in tr:
                t[:, _AXES.index(dof[i][1])] = v[:, i]
            if k == 0:
                root += t
            else:
                translations[k] = sk.offsets[k] + quat_rotate(c, t)
        if "l" in dof:
            lengths[k] = v[:, dof.index("l")]
    for k in range(1, j):
        p = int(sk.parents[k])
        if p in lengths:
            pb = asf.bones[sk.names[p]]
            extra = pb.direction * lengths[p][:, None]
            translations[k] = translations.get(k, np.broadcast_to(sk.offsets[k], (n_frames, 3))) + extra
    return Motion(
        skeleton=sk,
        fps=float(fps),
        root_positions=root,
        rotations=rotations,
        name=name if name is not None else (Path(path).stem if path else "motion"),
        source=path,
        content_hash=content_hash,
        unit=asf.unit,
        scale_to_m=asf.scale_to_m,
        translations=translations,
    )


def read_amc(path: str | Path, asf: AsfSkeleton | str | Path, *, fps: float = CMU_FPS,
             length_unit: str = "in") -> Motion:
    """Read an AMC file with its skeleton (an :class:`AsfSkeleton` or the ASF's path)."""
    if not isinstance(asf, AsfSkeleton):
        asf = read_asf(asf, length_unit=length_unit)
    text, digest = _read_text(path)
    return parse_amc(text, asf, str(path), fps=fps, content_hash=digest)


def read_asfamc(asf_path: str | Path, amc_path: str | Path, *, fps: float = CMU_FPS,
                length_unit: str = "in") -> Motion:
    """Read an ASF skeleton and an AMC motion into a :class:`Motion`."""
    return read_amc(amc_path, read_asf(asf_path, length_unit=length_unit), fps=fps)
