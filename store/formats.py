"""One entry point for every motion file format the project reads, and one for those it writes.

Read: ``.bvh`` (store.bvh), ``.amc`` with its ``.asf`` skeleton (store.asfamc) and DeepMimic
``.txt`` clips with their URDF humanoid (store.deepmimic). Write (:func:`write_motion`): ``.bvh``,
``.glb`` (glTF 2.0 binary, store.gltf) and ``.fbx`` (through Blender, store.fbx), chosen by the
output's suffix or by name.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from motionweb.store.errors import MissingSectionError, MotionFormatError, ReaderFailure, SidecarError
from motionweb.store.motion import UNIT_SCALES, Motion
from motionweb.store.textfile import decode, line_of, read_bytes

#: suffixes of files that hold a clip (an .asf alone is a skeleton, not a clip)
CLIP_SUFFIXES = (".bvh", ".amc", ".txt")


def is_clip(path: Path) -> bool:
    """Whether a file holds a clip we read (a .txt only when it is a DeepMimic JSON clip)."""
    suffix = path.suffix.lower()
    if suffix not in CLIP_SUFFIXES:
        return False
    if suffix == ".txt":
        with open(path, "rb") as fh:
            return b'"Frames"' in fh.read(4096)
    return True


def sidecar(path: Path) -> dict:
    """The ground-truth/metadata JSON written beside a clip (``<stem>.json``), or {}.

    Its ``unit`` must name a known length unit and its ``scale_to_m`` be a positive finite number
    (a bad sidecar is a :class:`SidecarError` naming the sidecar and the key)."""
    side = path.with_suffix(".json")
    if not side.is_file():
        return {}
    raw, _ = read_bytes(side)
    text = decode(raw)
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise SidecarError(str(side), line_of(text, exc.pos), f"bad JSON in the sidecar of {path.name}: {exc.msg}") from None
    except (RecursionError, ValueError) as exc:
        raise SidecarError(str(side), None, f"bad JSON in the sidecar of {path.name}: {type(exc).__name__}") from None
    if not isinstance(data, dict):
        return {}
    unit = data.get("unit")
    if unit is not None and (not isinstance(unit, str) or unit not in UNIT_SCALES):
        raise SidecarError(str(side), None, f"'unit' must be one of {', '.join(UNIT_SCALES)}, found {unit!r}")
    scale = data.get("scale_to_m")
    if scale is not None and (type(scale) not in (int, float) or not math.isfinite(scale) or scale <= 0):
        raise SidecarError(str(side), None, f"'scale_to_m' must be a positive finite number, found {scale!r}")
    return data


def find_asf(amc: Path) -> Path:
    """The ASF skeleton of a CMU AMC trial: ``<subject>.asf`` for ``<subject>_<trial>.amc``, or
    the only ``.asf`` in the folder."""
    subject = amc.stem.split("_")[0]
    candidate = amc.with_name(subject + ".asf")
    if candidate.is_file():
        return candidate
    asfs = sorted(amc.parent.glob("*.asf"))
    if len(asfs) == 1:
        return asfs[0]
    raise MissingSectionError(str(amc), None, f"no skeleton {candidate.name} (or a single .asf) beside the AMC file")


def read_motion(path: str | Path, *, unit: str | None = None, scale_to_m: float | None = None) -> Motion:
    """Read any supported clip. ``unit``/``scale_to_m`` apply where the file declares no unit
    (BVH); a sidecar JSON with a ``unit`` key takes precedence over them.

    Raises only :class:`MotionFormatError` subclasses: a fault a reader did not foresee becomes a
    :class:`ReaderFailure` naming the file (the fuzz tests require that none occurs).
    """
    path = Path(path)
    try:
        return _read_motion(path, unit, scale_to_m)
    except MotionFormatError:
        raise
    except Exception as exc:  # RecursionError and MemoryError included
        raise ReaderFailure(str(path), None, f"unreadable ({type(exc).__name__}: {exc})") from exc


def _read_motion(path: Path, unit: str | None, scale_to_m: float | None) -> Motion:
    suffix = path.suffix.lower()
    if suffix == ".bvh":
        from motionweb.store.bvh import read_bvh

        meta = sidecar(path)
        return read_bvh(path, unit=meta.get("unit", unit), scale_to_m=meta.get("scale_to_m", scale_to_m))
    if suffix == ".amc":
        from motionweb.store.asfamc import read_asfamc

        return read_asfamc(find_asf(path), path)
    if suffix == ".txt":
        from motionweb.store.deepmimic import read_deepmimic

        return read_deepmimic(path)
    raise MissingSectionError(str(path), None, f"unknown motion file type {suffix!r} (expected .bvh, .amc, .txt)")


#: formats a motion can be written in, by name; the suffix of an output names its format
WRITE_FORMATS = ("bvh", "glb", "fbx")


def motion_format(path: str | Path, fmt: str | None = None) -> str:
    """The format a motion is written in: ``fmt`` when given, else the output's suffix
    (``.bvh``, ``.glb``). ValueError naming the file or the format otherwise."""
    name = (fmt or Path(path).suffix.lstrip(".")).lower()
    if name in WRITE_FORMATS:
        return name
    if fmt:
        raise ValueError(f"unknown motion format {fmt!r}; expected one of {', '.join(WRITE_FORMATS)}")
    raise ValueError(f"{path}: cannot tell the motion format from the suffix; name the output "
                     f"with one of {', '.join('.' + f for f in WRITE_FORMATS)} (formats: {', '.join(WRITE_FORMATS)})")


def write_motion(motion: Motion, path: str | Path, fmt: str | None = None, *, up: str = "y") -> Path:
    """Write a motion in the format ``fmt`` or, without it, the one its suffix names: BVH
    (store.bvh, the file's unit and channel orders), GLB (store.gltf: metres, Y up, ``up``
    being the motion's vertical axis) or FBX (store.fbx: the GLB converted by Blender, which must
    be installed apart). Every command that writes a motion goes through here.
    Returns the path written."""
    path = Path(path)
    kind = motion_format(path, fmt)
    if kind == "glb":
        from motionweb.store.gltf import write_glb

        write_glb(motion, path, up=up)
    elif kind == "fbx":
        from motionweb.store.fbx import write_fbx

        write_fbx(motion, path, up=up)
    else:
        from motionweb.store.bvh import write_bvh

        write_bvh(motion, path)
    return path
