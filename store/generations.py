"""Generations: manifests of complete index runs, the ``current`` pointer, garbage collection (design §9).

Layout under the store root, beside the objects of ``store/zarr_store.py``::

    generations/<id>.json                        manifest of one complete run
    current                                      JSON pointer {"generation": <id>}

A generation becomes visible only when its manifest is written and ``current`` is switched to
it (an atomic rename on local disks, a single-object put on object stores), so readers never see
a half-written index and a crashed run leaves the previous one current. A pointer or current
manifest that cannot be read falls back, with a warning, to the newest manifest that can.
:func:`gc` keeps the current generation and the ``keep - 1`` committed before it and removes
everything else: older and uncommitted manifests, temporary files of killed writes, objects no
kept manifest lists, incomplete objects and shards that serve no kept web.
"""

from __future__ import annotations

import logging
import os
from dataclasses import asdict, dataclass, field
from importlib import metadata
from typing import Any

from motionweb.store.keys import SHARDS, STORE_SCHEMA, grid_key
from motionweb.store.zarr_store import MotionStore, StoreError, now_iso

log = logging.getLogger(__name__)

POINTER = "current"
#: manifest fields that differ between runs with the same content (see :func:`same_content`)
RUN_FIELDS = ("id", "created", "completed", "parent", "timings", "stats", "chunks")
PACKAGES = ("motionweb", "numpy", "scipy", "dask", "distributed", "zarr", "fsspec", "prefect", "prefect-dask")


def package_versions() -> dict[str, str]:
    """Installed versions of the packages that shape the results (recorded in each generation)."""
    out = {}
    for name in PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "absent"
    return out


@dataclass
class Generation:
    """The manifest of one complete index run: which content-addressed objects it includes.

    ``clips``: one record per indexed clip (path, sha256, category, frames, fps, skeleton, ...).
    ``features``: sha256 -> {rate tag: key}. ``webs``: one record per pair with keys ``a``, ``b``
    (corpus paths; ``a`` indexes the rows), ``a_sha``, ``b_sha``, ``key``, ``chunk`` and counts.
    ``broken``: files that could not be read, with the reason. ``skeleton``: per chunk, the
    majority signature and the clips indexed only against compatible ones. ``checksums``: object
    key -> SHA-256 of its bytes, for every feature object and web listed.
    """

    id: str
    created: str
    completed: str = ""
    parent: str | None = None
    store_schema: int = STORE_SCHEMA
    params: dict[str, Any] = field(default_factory=dict)
    config: dict[str, Any] = field(default_factory=dict)
    clips: list[dict[str, Any]] = field(default_factory=list)
    features: dict[str, dict[str, str]] = field(default_factory=dict)
    webs: list[dict[str, Any]] = field(default_factory=list)
    chunks: list[dict[str, Any]] = field(default_factory=list)
    broken: list[dict[str, str]] = field(default_factory=list)
    skeleton: list[dict[str, Any]] = field(default_factory=list)
    versions: dict[str, str] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)
    stats: dict[str, Any] = field(default_factory=dict)
    checksums: dict[str, str] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Generation:
        known = {k: v for k, v in d.items() if k in cls.__dataclass_fields__}
        return cls(**known)

    def web_for(self, path_a: str, path_b: str) -> tuple[dict[str, Any], bool] | None:
        """The web record of two clips (corpus paths) and whether it is stored transposed
        (rows = ``path_b``); None when the pair is not in this generation."""
        for w in self.webs:
            if w["a"] == path_a and w["b"] == path_b:
                return w, False
            if w["a"] == path_b and w["b"] == path_a:
                return w, True
        return None


def same_content(a: Generation, b: Generation) -> bool:
    """Whether two manifests list the same content (clips, objects, checksums, config), whatever
    their ids, times and per-run counts."""
    def content(g: Generation) -> dict[str, Any]:
        d = {k: v for k, v in g.to_dict().items() if k not in RUN_FIELDS}
        d["webs"] = [{k: v for k, v in w.items() if k != "computed"} for w in g.webs]
        return d

    return content(a) == content(b)


def _manifest(store: MotionStore, gen_id: str) -> Generation:
    return Generation.from_dict(store.read_json(f"generations/{gen_id}.json"))


def _readable_fallback(store: MotionStore, why: str) -> str | None:
    """The newest manifest that reads, after a warning saying why the pointer was not used."""
    for gid in reversed(generation_ids(store)):
        try:
            g = _manifest(store, gid)
        except (OSError, ValueError, TypeError):
            continue
        if g.completed:
            log.warning("%s: %s; falling back to generation %s", store.url, why, gid)
            return gid
    log.warning("%s: %s and no manifest is readable", store.url, why)
    return None


def current_id(store: MotionStore) -> str | None:
    """Id of the current (last completely committed) generation, None for a new store.

    A pointer that is unreadable or names an unreadable manifest falls back to the newest
    readable manifest, with a warning."""
    try:
        gid = store.read_json(POINTER)["generation"]
    except FileNotFoundError:
        return _readable_fallback(store, "no 'current' pointer") if generation_ids(store) else None
    except (ValueError, TypeError, KeyError) as exc:
        return _readable_fallback(store, f"the 'current' pointer is damaged ({type(exc).__name__})")
    try:
        _manifest(store, gid)
    except (OSError, ValueError, TypeError) as exc:
        return _readable_fallback(store, f"current manifest {gid} is unreadable ({type(exc).__name__})")
    return gid


def load_generation(store: MotionStore, gen_id: str | None = None) -> Generation | None:
    """A generation's manifest (the current one by default); None when there is none."""
    gen_id = gen_id or current_id(store)
    if gen_id is None:
        return None
    try:
        return _manifest(store, gen_id)
    except (OSError, ValueError, TypeError) as exc:
        raise StoreError(store.url, f"generations/{gen_id}.json", f"is unreadable ({type(exc).__name__})") from None


def generation_ids(store: MotionStore) -> list[str]:
    """Manifests in the store, oldest first (ids sort by time)."""
    try:
        names = store.fs.ls(store.path("generations"), detail=False)
    except FileNotFoundError:
        return []
    return sorted(os.path.basename(n)[:-5] for n in names if n.endswith(".json"))


@dataclass(frozen=True)
class Problem:
    """One object of a generation that cannot be used: what it is (clip or web), key, reason."""

    what: str
    key: str
    reason: str

    def __str__(self) -> str:
        return f"{self.what} ({self.key}): {self.reason}"


def verify_generation(store: MotionStore, gen: Generation) -> list[Problem]:
    """Every feature object and web a generation lists, read whole and checked against the
    checksums recorded with it and in the manifest. Cost: one read of the generation's objects."""
    clip_of = {c["sha256"]: c["path"] for c in gen.clips}
    problems = []
    for sha, rates in sorted(gen.features.items()):
        for key in sorted(set(rates.values())):
            if (reason := store.verify(key, gen.checksums.get(key))) is not None:
                problems.append(Problem(f"features of {clip_of.get(sha, sha[:12])}", key, reason))
    for w in gen.webs:
        if (reason := store.verify(w["key"], gen.checksums.get(w["key"]))) is not None:
            problems.append(Problem(f"web {w['a']} x {w['b']}", w["key"], reason))
    return problems


def commit(store: MotionStore, gen: Generation) -> str:
    """Publish a generation: write its manifest, then switch ``current`` to it.

    Every object it lists must already be complete (checked); until the pointer moves the
    previous generation stays current.
    """
    if store.read_only:
        raise PermissionError(f"{store.url}: store opened read-only")
    missing = [w["key"] for w in gen.webs if not store.has(w["key"])]
    missing += [k for rates in gen.features.values() for k in set(rates.values()) if not store.has(k)]
    if missing:
        raise RuntimeError(f"refusing to commit generation {gen.id}: {len(missing)} objects missing, "
                           f"e.g. {missing[0]}")
    store.ensure_root()
    gen.completed = gen.completed or now_iso()
    store.write_json(f"generations/{gen.id}.json", gen.to_dict())
    store.write_json(POINTER, {"generation": gen.id, "committed": gen.completed})
    return gen.id


def gc(store: MotionStore, keep: int = 3) -> list[str]:
    """Remove what no kept generation needs; returns the removed keys (objects and files).

    Kept: the current generation and the ``keep - 1`` manifests committed before it. Removed:
    other manifests (older ones, and uncommitted ones newer than the current), ``*.tmp-*`` files
    of killed writes, feature and grid objects no kept manifest lists (or left incomplete), and
    shards that serve no kept web (orphans of killed runs, superseded or damaged shards). Never
    run it concurrently with an index run (``motionweb index`` runs it after its commit).
    """
    if keep < 1:
        raise ValueError(f"gc keeps at least the current generation (keep={keep})")
    ids = generation_ids(store)
    cur = current_id(store)
    if cur is None:
        return []
    committed = [i for i in ids if i <= cur]
    kept = set(committed[-keep:]) | {cur}
    live: set[str] = set()
    for gid in sorted(kept):
        try:
            g = _manifest(store, gid)
        except (OSError, ValueError, TypeError):
            kept.discard(gid)
            continue
        live |= {w["key"] for w in g.webs} | {grid_key(w["key"]) for w in g.webs}
        live |= {k for rates in g.features.values() for k in rates.values()}
    removed: list[str] = []
    for top, depth in (("features", 3), ("grids", 3)):
        for key in store.leaf_keys(top, depth):
            if key not in live or not store.has(key):
                store.delete(key)
                removed.append(key)
    serving = {store.web_shard(k) for k in live if k.startswith("webs/")}
    for shard in store.leaf_keys(SHARDS, 2):
        if shard not in serving:
            store.delete(shard)
            removed.append(shard)
    for gid in set(ids) - kept:
        store.fs.rm(store.path(f"generations/{gid}.json"))
        removed.append(f"generations/{gid}.json")
    for folder in ("", "generations"):
        try:
            names = store.fs.ls(store.path(folder) if folder else store.root, detail=False)
        except FileNotFoundError:
            continue
        for name in names:
            if ".tmp-" in os.path.basename(name):
                store.fs.rm(name)
                removed.append(f"{folder}/{os.path.basename(name)}".lstrip("/"))
    return removed
