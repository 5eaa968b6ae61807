"""Generations: manifests of complete index runs, the ``current`` pointer, garbage collection (design §9).

Layout under the store root, beside the objects of ``store/zarr_store.py``::

    generations/<id>.json                        manifest of one complete run
    current                                      JSON pointer {"generation": <id>}

A generation becomes visible only when its manifest is written and ``current`` is switched to
it (an atomic rename on local disks, a single-object put on object stores), so readers never see
a half-written index and a crashed run leaves the previous one current.
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass, field
from importlib import metadata
from typing import Any

from motionweb.store.keys import SHARDS, STORE_SCHEMA, grid_key
from motionweb.store.zarr_store import MotionStore, now_iso

POINTER = "current"
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
    majority signature and the clips indexed only against compatible ones.
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


def current_id(store: MotionStore) -> str | None:
    """Id of the current (last completely committed) generation, None for a new store."""
    try:
        return store.read_json(POINTER)["generation"]
    except FileNotFoundError:
        return None


def load_generation(store: MotionStore, gen_id: str | None = None) -> Generation | None:
    """A generation's manifest (the current one by default); None when there is none."""
    gen_id = gen_id or current_id(store)
    if gen_id is None:
        return None
    return Generation.from_dict(store.read_json(f"generations/{gen_id}.json"))


def generation_ids(store: MotionStore) -> list[str]:
    """Committed manifests, oldest first (ids sort by time)."""
    try:
        names = store.fs.ls(store.path("generations"), detail=False)
    except FileNotFoundError:
        return []
    return sorted(os.path.basename(n)[:-5] for n in names if n.endswith(".json"))


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
    """Delete objects no kept generation lists (the ``keep`` newest plus the current one).

    Returns the deleted keys. Never run concurrently with an index run.
    """
    ids = generation_ids(store)
    cur = current_id(store)
    kept = set(ids[-keep:]) | ({cur} if cur else set())
    live: set[str] = set()
    for gid in kept:
        g = load_generation(store, gid)
        live |= {w["key"] for w in g.webs} | {grid_key(w["key"]) for w in g.webs}
        live |= {k for rates in g.features.values() for k in rates.values()}
    dropped: list[str] = []
    for top, depth in (("features", 3), ("grids", 3)):
        for key in store.leaf_keys(top, depth):
            if key not in live:
                store.delete(key)
                dropped.append(key)
    for shard in store.leaf_keys(SHARDS, 2):  # a shard goes when none of its webs is live
        keys = store.shard_web_keys(shard)
        if not live.intersection(keys):
            store.delete(shard)
            dropped += keys
    for gid in set(ids) - kept:
        store.fs.rm(store.path(f"generations/{gid}.json"))
    return dropped
