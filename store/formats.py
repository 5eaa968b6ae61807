"""One entry point for every motion file format the project reads.

``.bvh`` (store.bvh), ``.amc`` with its ``.asf`` skeleton (store.asfamc) and DeepMimic ``.txt``
clips with their URDF humanoid (store.deepmimic).
"""

from __future__ import annotations

import json
from pathlib import Path

from motionweb.store.errors import MissingSectionError
from motionweb.store.motion import Motion

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
    """The ground-truth/metadata JSON written beside a clip (``<stem>.json``), or {}."""
    side = path.with_suffix(".json")
    if not side.is_file():
        return {}
    try:
        data = json.loads(side.read_text())
    except (OSError, json.JSONDecodeError):
        return {}
    return data if isinstance(data, dict) else {}


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
    (BVH); a sidecar JSON with a ``unit`` key takes precedence over them."""
    path = Path(path)
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
