"""The corpus catalog: scan a folder of clips, label each with a category, hash and describe it.

Labels come from, in order of precedence: a manifest CSV (``path,category``), the first matching
regex rule of the config, the first folder level under the corpus root. An unreadable file is
reported with its reason and skipped; the scan goes on. Cost: one full parse per clip, O(corpus
bytes), the files shared among one thread per core (a 1e6-frame corpus of long takes: 11 s → 7.5 s on 2).
"""

from __future__ import annotations

import csv
import json
import os
import re
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Literal

from motionweb.store.errors import MotionFormatError
from motionweb.store.formats import is_clip, read_motion, sidecar
from motionweb.store.motion import Motion
from motionweb.store.params import Params
from motionweb.store.textfile import read_bytes
from motionweb.store.threads import IO_THREADS, map_in_threads
from pydantic import Field


class CategoryRule(Params):
    """Clips whose corpus-relative path matches ``pattern`` (Python regex, searched) get ``category``."""

    pattern: str
    category: str


class CorpusParams(Params):
    path: str = "demo-corpus"
    #: regex rules tried in order; the first folder level labels clips no rule matches
    category_rules: list[CategoryRule] = Field(default_factory=list)
    #: CSV with columns ``path,category`` (paths relative to the corpus); overrides rules
    manifest: str | None = None
    #: length unit of files that do not declare one (BVH): m, cm, mm, in, ft
    length_unit: str | None = None
    scale_to_m: float | None = None
    up_axis: Literal["x", "y", "z"] = "y"



UNCATEGORIZED = "uncategorized"
FORMAT_NAMES = {".bvh": "bvh", ".amc": "asfamc", ".txt": "deepmimic"}


@dataclass(frozen=True)
class ClipEntry:
    """One clip of the corpus. ``path`` is corpus-relative (POSIX), ``sha256`` the file's hash."""

    path: str
    abs_path: str
    category: str
    sha256: str
    format: str
    fps: float
    frames: int
    duration: float
    skeleton: str
    n_joints: int
    unit: str | None

    @property
    def name(self) -> str:
        return Path(self.path).stem


@dataclass(frozen=True)
class ScanError:
    """A file that could not be read, and why."""

    path: str
    reason: str


@dataclass
class Catalog:
    root: str
    entries: list[ClipEntry] = field(default_factory=list)
    errors: list[ScanError] = field(default_factory=list)

    def by_category(self) -> dict[str, list[ClipEntry]]:
        groups: dict[str, list[ClipEntry]] = {}
        for e in self.entries:
            groups.setdefault(e.category, []).append(e)
        return dict(sorted(groups.items()))

    def find(self, name_or_path: str) -> ClipEntry:
        """The entry whose relative path, stem or absolute path is ``name_or_path``."""
        target = str(Path(name_or_path).resolve()) if Path(name_or_path).exists() else None
        for e in self.entries:
            if name_or_path in (e.path, e.name) or target == e.abs_path:
                return e
        raise KeyError(f"no clip {name_or_path!r} in the catalog of {self.root}")

    def to_dict(self) -> dict:
        return {
            "root": self.root,
            "clips": [asdict(e) for e in self.entries],
            "errors": [asdict(e) for e in self.errors],
        }

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2, sort_keys=True)


def _read_manifest(path: str) -> dict[str, str]:
    labels: dict[str, str] = {}
    with open(path, newline="") as fh:
        reader = csv.DictReader(fh)
        if reader.fieldnames is None or not {"path", "category"} <= set(reader.fieldnames):
            raise ValueError(f"{path}: the manifest needs the columns 'path,category'")
        for row in reader:
            labels[Path(row["path"]).as_posix()] = row["category"]
    return labels


def label(rel: str, cfg: CorpusParams, manifest: dict[str, str]) -> str:
    """The category of a corpus-relative path (manifest, then rules, then first folder level)."""
    if rel in manifest:
        return manifest[rel]
    for rule in cfg.category_rules:
        if re.search(rule.pattern, rel):
            return rule.category
    parts = Path(rel).parts
    return parts[0] if len(parts) > 1 else UNCATEGORIZED


def load_clip(entry: ClipEntry, cfg: CorpusParams) -> Motion:
    """Read the clip of a catalog entry, with the config's unit for files that declare none."""
    motion = read_motion(entry.abs_path, unit=cfg.length_unit, scale_to_m=cfg.scale_to_m)
    if motion.content_hash != entry.sha256:
        raise MotionFormatError(entry.abs_path, None, "the file changed since it was catalogued; rescan")
    return motion


def corpus_files(root: Path) -> list[Path]:
    """Every file under ``root``, sorted, following directory symlinks; a folder reached again
    (a symlink loop, or two links to one folder) is walked once."""
    seen: set[tuple[int, int]] = set()
    out: list[Path] = []
    for folder, dirs, files in os.walk(root, followlinks=True):
        try:
            st = os.stat(folder)
        except OSError:
            dirs[:] = []
            continue
        if (st.st_dev, st.st_ino) in seen:
            dirs[:] = []
            continue
        seen.add((st.st_dev, st.st_ino))
        dirs.sort()
        out += [Path(folder, f) for f in files if os.path.isfile(os.path.join(folder, f))]
    return sorted(out)


def _known_entry(path: Path, rel: str, category: str, known: dict | None, unit: str | None) -> ClipEntry | None:
    """The entry of a BVH clip described before (``known``: its record then, as a generation's
    ``clips`` list it) when the file's bytes still have that record's SHA-256 and it reads in the
    record's unit (its sidecar's ``unit``, else the corpus's ``unit``): a BVH's entry depends on
    nothing else (its skeleton's signature is its topology; a sidecar's ``scale_to_m`` scales
    positions, which no entry field holds). None otherwise (the file is read whole). Costs a
    read and a SHA-256 of the file (and its sidecar's parse), not the clip's parse."""
    if known is None or path.suffix.lower() != ".bvh":
        return None
    raw, digest = read_bytes(path)
    if digest != known.get("sha256") or known.get("unit") != sidecar(path).get("unit", unit):
        return None
    try:
        return ClipEntry(path=rel, abs_path=str(path), category=category, sha256=digest, format=FORMAT_NAMES[".bvh"],
                         fps=float(known["fps"]), frames=int(known["frames"]), duration=float(known["duration"]),
                         skeleton=str(known["skeleton"]), n_joints=int(known["n_joints"]),
                         unit=None if known["unit"] is None else str(known["unit"]))
    except (KeyError, TypeError, ValueError):
        return None


def scan_corpus(root: str | Path, cfg: CorpusParams | None = None, threads: int | None = None,
                known: Mapping[str, dict] | None = None) -> Catalog:
    """Scan ``root`` recursively (following directory symlinks); every readable clip becomes a
    :class:`ClipEntry` (sorted by path), every file that fails is listed in ``errors`` with the
    reason and the scan goes on. The files are read by ``threads`` threads (default: one per
    core, at most 8; reading, hashing and the BVH frame parser release the GIL); the catalog is
    the same whatever their number. Cost O(corpus bytes) / threads.

    ``known``: clips described before with this corpus's unit, by corpus-relative path (a
    nightly rerun passes the current generation's, ``flows/index.py`` ``known_clips``): a BVH
    whose bytes are unchanged is described from its record, hashed but not parsed
    (:func:`_known_entry`; the same entry, tested). The 381k-frame demo corpus's scan took ~5 s
    of a 21 s rerun with nothing changed, parsing 1,620 clips again."""
    cfg = cfg or CorpusParams(path=str(root))
    root = Path(root).resolve()
    if not root.is_dir():
        raise FileNotFoundError(f"corpus folder {root} does not exist")
    manifest = _read_manifest(cfg.manifest) if cfg.manifest else {}
    catalog = Catalog(root=str(root))

    def describe(path: Path) -> ClipEntry | ScanError | None:
        rel = path.relative_to(root).as_posix()
        try:
            if not is_clip(path):
                return None
            if known and (entry := _known_entry(path, rel, label(rel, cfg, manifest), known.get(rel),
                                                cfg.length_unit)) is not None:
                return entry
            motion = read_motion(path, unit=cfg.length_unit, scale_to_m=cfg.scale_to_m)
        except Exception as exc:  # any per-file failure is listed, never raised: the scan goes on
            return ScanError(rel, str(exc) if isinstance(exc, MotionFormatError) else f"{type(exc).__name__}: {exc}")
        return ClipEntry(
            path=rel,
            abs_path=str(path),
            category=label(rel, cfg, manifest),
            sha256=motion.content_hash,
            format=FORMAT_NAMES[path.suffix.lower()],
            fps=float(motion.fps),
            frames=motion.n_frames,
            duration=motion.duration,
            skeleton=motion.skeleton.signature(),
            n_joints=motion.skeleton.n_joints,
            unit=motion.unit,
        )

    for found in map_in_threads(describe, corpus_files(root), threads, IO_THREADS, "scan"):  # in file order
        if isinstance(found, ScanError):
            catalog.errors.append(found)
        elif found is not None:
            catalog.entries.append(found)
    return catalog
