"""The content-addressed Zarr v3 store of features and match webs, with generations (design §9).

Layout under the store root (a local folder or any fsspec URL)::

    zarr.json                                    root group
    features/<sha[:2]>/<sha>/<fdig>              one packed uint8 array per clip and feature
                                                 parameters: its (F_rate, P, 3) point clouds per
                                                 rate (r10, r20, r30 ..., design §3) and (P,) point
                                                 weights back to back, laid out in its attributes
    webs/shards/<wdig>/<shard id>                one packed uint8 array per written batch of webs:
                                                 the flat arrays of MatchWeb.to_arrays() (ragged
                                                 paths as values + offsets, KG04 §3.2) of each web
                                                 back to back; its attributes map every web key
                                                 (webs/<sha_a[:2]>/<sha_a>-<sha_b>/<wdig>, one
                                                 per ordered clip pair and web parameters) to its
                                                 byte range, array layout and attributes
    grids/...                                    full grids, only with matchweb.keep_grids
    generations/<id>.json                        manifest of one complete run
    current                                      JSON pointer {"generation": <id>}

Objects are keyed by content: a clip by the SHA-256 of its file, a derived array additionally by
a digest of the parameters that produce it, so objects are shared by every generation that
lists them and a rerun recomputes only what is missing. An object is marked ``complete`` in its
attributes only after all its arrays are written; a half-written object is never seen as
present. Webs are many and small (zarr costs ~2 ms of CPU per array created), so a batch of webs
shares one array (a shard) and a web key is found through the index in the shards' attributes,
listed once per store instance and again when a key is not found. A generation becomes visible
only when its manifest is written and ``current`` is switched to it (an atomic rename on local
disks, a single-object put on object stores), so readers never see a half-written index and a
crashed run leaves the previous one current.
"""

from __future__ import annotations

import hashlib
import json
import os
import uuid
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from importlib import metadata
from typing import TYPE_CHECKING, Any, Protocol

import fsspec
import numpy as np
import zarr
from motionweb.store.params import Params
from motionweb.store.web import MatchWeb
from zarr.codecs import BloscCodec
from zarr.storage import FsspecStore, LocalStore

if TYPE_CHECKING:
    from motionweb.store.catalog import CorpusParams


class IndexSettings(Protocol):
    """What keys the index: a run config's corpus, features and matchweb sections (duck-typed, so
    the store needs none of the stages that define them)."""

    corpus: CorpusParams
    features: Params
    matchweb: Params

#: bump when the layout or the meaning of stored arrays changes (enters every parameter digest)
STORE_SCHEMA = 2
#: Blosc lz4 + byte shuffle: fastest writes and a better ratio on float32 (measured on this store)
COMPRESSORS = (BloscCodec(cname="lz4", clevel=5, shuffle="shuffle"),)
#: frames per chunk along the first axis of large arrays (2000-4000 rows wrote fastest when measured)
CHUNK_ROWS = 4096
#: bytes per chunk of a packed object (one chunk for most clips' features)
PACKED_CHUNK = 1 << 24
#: bytes per chunk of a web shard (a web read decodes ~1-2 chunks, not the whole shard)
SHARD_CHUNK = 1 << 18
#: web shards live under webs/ next to the (logical) web keys webs/<sha_a[:2]>/...
SHARDS = "webs/shards"
POINTER = "current"
PACKAGES = ("motionweb", "numpy", "scipy", "dask", "distributed", "zarr", "fsspec", "prefect", "prefect-dask")


def _digest(data: Any) -> str:
    return hashlib.sha256(json.dumps(data, sort_keys=True, default=str).encode()).hexdigest()


def feature_params(cfg: IndexSettings) -> dict[str, Any]:
    """Everything that changes a clip's features at one rate (the rate list itself excluded)."""
    feats = cfg.features.model_dump(mode="json")
    feats.pop("rates", None)
    corpus = cfg.corpus
    return {
        "schema": STORE_SCHEMA,
        "features": feats,
        "up_axis": corpus.up_axis,
        "length_unit": corpus.length_unit,
        "scale_to_m": corpus.scale_to_m,
    }


def feature_digest(cfg: IndexSettings) -> str:
    """Parameter hash keying features: clip sha256 + this + rate (design §9)."""
    return _digest(feature_params(cfg))[:16]


def web_params(cfg: IndexSettings) -> dict[str, Any]:
    """Everything that changes a web: feature parameters, the rate ladder and the matchweb section."""
    mw = cfg.matchweb.model_dump(mode="json")
    mw.pop("keep_grids", None)  # storing grids on the side does not change a web
    return {
        "schema": STORE_SCHEMA,
        "features": feature_params(cfg),
        "rates": sorted(float(r) for r in cfg.features.rates),
        "matchweb": mw,
    }


def web_digest(cfg: IndexSettings) -> str:
    """Parameter hash keying webs: ordered pair of clip hashes + this (design §9)."""
    return _digest(web_params(cfg))[:16]


def rate_tag(rate: float) -> str:
    """Array name of one feature rate, e.g. ``r30`` or ``r7.5``."""
    return f"r{float(rate):g}"


def feature_key(sha: str, fdigest: str) -> str:
    return f"features/{sha[:2]}/{sha}/{fdigest}"


def web_key(sha_a: str, sha_b: str, wdigest: str) -> str:
    """Key of the web whose rows are clip ``sha_a`` and columns clip ``sha_b``."""
    return f"webs/{sha_a[:2]}/{sha_a}-{sha_b}/{wdigest}"


def grid_key(web: str) -> str:
    return "grids/" + web.removeprefix("webs/")


def _web_digest_of(key: str) -> str:
    """The web parameter digest at the end of a web key (names the key's shard folder)."""
    return key.rsplit("/", 1)[-1]


def _pack(arrays: dict[str, np.ndarray], start: int = 0) -> tuple[list[np.ndarray], list[list[Any]], int]:
    """Byte views of arrays and their layout rows ``[name, dtype, shape, start, nbytes]``."""
    layout, parts = [], []
    for name, value in arrays.items():
        a = np.ascontiguousarray(value)
        layout.append([name, a.dtype.str, list(a.shape), start, a.nbytes])
        parts.append(a.view(np.uint8).reshape(-1))
        start += a.nbytes
    return parts, layout, start


def _unpack(buf: np.ndarray, layout: list[list[Any]], base: int = 0) -> dict[str, np.ndarray]:
    """Inverse of :func:`_pack` on ``buf`` holding the bytes from offset ``base`` on."""
    return {name: buf[start - base:start - base + nbytes].view(np.dtype(dtype)).reshape(shape).copy()
            for name, dtype, shape, start, nbytes in layout}


def package_versions() -> dict[str, str]:
    """Installed versions of the packages that shape the results (recorded in each generation)."""
    out = {}
    for name in PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "absent"
    return out


def now_iso() -> str:
    return datetime.now(UTC).isoformat(timespec="milliseconds")


def new_generation_id() -> str:
    """Sortable, unique: UTC timestamp plus a random suffix."""
    return datetime.now(UTC).strftime("%Y%m%dT%H%M%S%fZ") + "-" + uuid.uuid4().hex[:6]


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


class MotionStore:
    """A Zarr v3 store of features and webs with generation manifests (design §9).

    ``url`` is a local folder or any fsspec URL (``memory://``, ``s3://``, ``file://`` ...).
    Instances are cheap and picklable by URL, so Dask workers open their own.
    """

    def __init__(self, url: str, read_only: bool = False):
        self.url = str(url)
        self.read_only = read_only
        self.fs, self.root = fsspec.core.url_to_fs(self.url)
        self._local = "://" not in self.url or self.url.startswith("file://")
        if self._local:
            if not read_only:
                os.makedirs(self.root, exist_ok=True)
            self.zstore = LocalStore(self.root, read_only=read_only)
        else:
            self.zstore = FsspecStore.from_url(self.url, read_only=read_only)
        # web key -> (shard key, its entry), from the attributes of the complete shards seen so far
        self._webs: dict[str, tuple[str, dict[str, Any]]] = {}
        # complete shards seen so far, kept open: opening one parses its whole index of webs
        self._shards: dict[str, zarr.Array] = {}

    def __reduce__(self):
        return (MotionStore, (self.url, self.read_only))

    def __repr__(self) -> str:
        return f"MotionStore({self.url!r})"

    # ---------------------------------------------------------------- objects
    def _open(self, key: str) -> zarr.Group | zarr.Array | None:
        """The group (features, grids) or packed array (webs) stored at ``key``, None if absent."""
        try:
            return zarr.open(store=self.zstore, path=key, mode="r")
        except (FileNotFoundError, zarr.errors.NodeNotFoundError, KeyError):
            return None

    def has(self, key: str) -> bool:
        """True when the object (a web, or a features / grid group) exists and was completely written."""
        if key.startswith("webs/"):
            return self._web_entry(key) is not None
        g = self._open(key)
        return g is not None and bool(g.attrs.get("complete", False))

    def _write_packed(self, key: str, arrays: dict[str, np.ndarray], attrs: dict[str, Any]) -> None:
        """Write small arrays as ONE uint8 Zarr array (bytes concatenated, layout in attrs).

        A web is ~10 small arrays, a clip's features 4; zarr's per-array overhead (~2 ms of CPU
        per array created, plus one per write) dominates such objects, so one array each costs
        a fraction of a group of arrays. Marked complete last.
        """
        parts, layout, _ = _pack(arrays)
        self._write_bytes(key, parts, PACKED_CHUNK, {**attrs, "layout": layout})

    def _write_bytes(self, key: str, parts: list[np.ndarray], chunk: int, attrs: dict[str, Any]) -> zarr.Array:
        """One uint8 Zarr array of the concatenated ``parts``, marked complete after its data."""
        buf = np.concatenate(parts) if parts else np.zeros(0, np.uint8)
        z = zarr.create_array(self.zstore, name=key, shape=buf.shape, chunks=(max(1, min(buf.size, chunk)),),
                              dtype=np.uint8, compressors=COMPRESSORS, overwrite=True,
                              attributes={**attrs, "written": now_iso()})
        if buf.size:
            z[...] = buf
        z.update_attributes({"complete": True})
        return z

    def _read_packed(self, key: str) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        z = self._open(key)
        if z is None or not z.attrs.get("complete", False):
            raise KeyError(f"{self.url}: no complete object {key!r}")
        attrs = dict(z.attrs)
        buf = np.asarray(z[...]) if z.shape[0] else np.zeros(0, np.uint8)
        return _unpack(buf, attrs.pop("layout")), attrs

    def _write_group(self, key: str, arrays: dict[str, np.ndarray], attrs: dict[str, Any]) -> None:
        """Write arrays into a fresh group; mark it complete last (a crash leaves it incomplete)."""
        g = zarr.open_group(store=self.zstore, path=key, mode="w")
        for name, value in arrays.items():
            arr = np.ascontiguousarray(value)
            chunks = tuple(max(1, s) for s in arr.shape)
            if arr.ndim:
                chunks = (min(chunks[0], CHUNK_ROWS), *chunks[1:])
            z = g.create_array(
                name, shape=arr.shape, chunks=chunks, dtype=arr.dtype,
                compressors=COMPRESSORS if arr.dtype.kind in "fiub" else "auto",
            )
            if arr.size:
                z[...] = arr
        g.update_attributes({**attrs, "written": now_iso(), "complete": True})

    def _read_group(self, key: str, names: list[str] | None = None) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        g = self._open(key)
        if g is None or not g.attrs.get("complete", False):
            raise KeyError(f"{self.url}: no complete object {key!r}")
        keys = names if names is not None else sorted(g.array_keys())
        return {k: np.asarray(g[k][...]) for k in keys}, dict(g.attrs)

    # features
    def has_features(self, sha: str, fdigest: str, rates: list[float]) -> bool:
        z = self._open(feature_key(sha, fdigest))
        if z is None or not z.attrs.get("complete", False):
            return False
        have = {entry[0] for entry in z.attrs.get("layout", [])}
        return all(rate_tag(r) in have for r in rates) and "weights" in have

    def write_features(
        self, sha: str, fdigest: str, by_rate: dict[float, np.ndarray], weights: np.ndarray,
        attrs: dict[str, Any] | None = None,
    ) -> str:
        """Store a clip's point clouds at each rate plus its point weights (packed); returns the key."""
        key = feature_key(sha, fdigest)
        arrays = {rate_tag(r): f for r, f in by_rate.items()}
        arrays["weights"] = np.asarray(weights)
        self._write_packed(key, arrays, {"sha256": sha, "rates": sorted(map(float, by_rate)), **(attrs or {})})
        return key

    def read_features(
        self, sha: str, fdigest: str, rates: list[float] | None = None
    ) -> tuple[dict[float, np.ndarray], np.ndarray]:
        """(features by rate, point weights) of one clip."""
        try:
            arrays, attrs = self._read_packed(feature_key(sha, fdigest))
        except KeyError:
            raise KeyError(f"{self.url}: no features for clip {sha[:12]} with parameters {fdigest}") from None
        rates = rates if rates is not None else attrs["rates"]
        return {float(r): arrays[rate_tag(r)] for r in rates}, arrays["weights"]

    # webs
    def write_webs(self, webs: list[tuple[str, dict[str, np.ndarray], dict[str, Any]]]) -> None:
        """Store webs ``(key, flat arrays of MatchWeb.to_arrays(), attributes)`` as one shard per
        web parameter digest: one Zarr array for the whole batch, O(1) Zarr calls per batch."""
        by_digest: dict[str, list[tuple[str, dict[str, np.ndarray], dict[str, Any]]]] = {}
        for item in webs:
            by_digest.setdefault(_web_digest_of(item[0]), []).append(item)
        for wdig, items in by_digest.items():
            parts, entries, start = [], {}, 0
            for key, arrays, attrs in items:
                p, layout, end = _pack(arrays, start)
                parts += p
                entries[key] = {"start": start, "nbytes": end - start, "layout": layout, "attrs": attrs}
                start = end
            shard = f"{SHARDS}/{wdig}/{new_generation_id()}"
            self._shards[shard] = self._write_bytes(shard, parts, SHARD_CHUNK, {"webs": entries})
            self._webs.update({key: (shard, e) for key, e in entries.items()})

    def write_web(self, key: str, arrays: dict[str, np.ndarray], attrs: dict[str, Any] | None = None) -> None:
        """Store one web's flat arrays (``MatchWeb.to_arrays()``) under ``key``."""
        self.write_webs([(key, arrays, attrs or {})])

    def _web_entry(self, key: str) -> tuple[str, dict[str, Any]] | None:
        """(shard, entry) of a web key; lists the digest's shards again when the key is unknown."""
        if key not in self._webs:
            self._load_shards(_web_digest_of(key))
        return self._webs.get(key)

    def _load_shards(self, wdig: str) -> None:
        try:
            entries = self.fs.ls(self._path(f"{SHARDS}/{wdig}"), detail=True)
        except FileNotFoundError:
            return
        for name in sorted(e["name"] for e in entries if e["type"] == "directory"):
            shard = f"{SHARDS}/{wdig}/{os.path.basename(name.rstrip('/'))}"
            if shard in self._shards:
                continue
            z = self._open(shard)
            if z is None or not z.attrs.get("complete", False):
                continue  # being written, or its writer died: not seen yet
            self._shards[shard] = z
            self._webs.update({key: (shard, e) for key, e in z.attrs["webs"].items()})

    def web_keys(self, wdig: str) -> set[str]:
        """Every completely written web key with parameter digest ``wdig`` (one shard listing)."""
        self._load_shards(wdig)
        return {k for k in self._webs if _web_digest_of(k) == wdig}

    def web_attrs(self, key: str) -> dict[str, Any]:
        """The attributes a web was written with ({} when absent)."""
        found = self._web_entry(key)
        return dict(found[1]["attrs"]) if found else {}

    def read_web_arrays(self, key: str) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """The flat arrays of a web (names, dtypes and shapes as written) and its attributes."""
        found = self._web_entry(key)
        z = (self._shards.get(found[0]) or self._open(found[0])) if found else None
        if z is None:
            raise KeyError(f"{self.url}: no complete web {key!r}")
        e = found[1]
        buf = np.asarray(z[e["start"]:e["start"] + e["nbytes"]]) if e["nbytes"] else np.zeros(0, np.uint8)
        return _unpack(buf, e["layout"], e["start"]), dict(e["attrs"])

    def read_web(self, key: str) -> MatchWeb:
        """The stored web as a ``tasks.matchweb.MatchWeb``."""

        arrays, _ = self.read_web_arrays(key)
        return MatchWeb.from_arrays(arrays)

    def write_grid(self, web: str, grid: np.ndarray) -> None:
        """Keep a full distance grid next to a web (``matchweb.keep_grids``; plots, debugging)."""
        self._write_group(grid_key(web), {"grid": grid}, {"web": web})

    def read_grid(self, web: str) -> np.ndarray:
        return self._read_group(grid_key(web), ["grid"])[0]["grid"]

    # ------------------------------------------------------------ generations
    def _path(self, rel: str) -> str:
        return f"{self.root.rstrip('/')}/{rel}"

    def _write_json(self, rel: str, data: Any, atomic: bool = True) -> None:
        """Write a JSON file; on local disks by rename of a temp file (atomic), elsewhere by one put."""
        payload = json.dumps(data, indent=1, sort_keys=True, default=str).encode()
        path = self._path(rel)
        self.fs.makedirs(os.path.dirname(path) or self.root, exist_ok=True)
        if self._local and atomic:
            tmp = f"{path}.tmp-{uuid.uuid4().hex[:8]}"
            with open(tmp, "wb") as fh:
                fh.write(payload)
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, path)
        else:
            self.fs.pipe_file(path, payload)

    def _read_json(self, rel: str) -> Any:
        return json.loads(self.fs.cat_file(self._path(rel)))

    def current_id(self) -> str | None:
        """Id of the current (last completely committed) generation, None for a new store."""
        try:
            return self._read_json(POINTER)["generation"]
        except FileNotFoundError:
            return None

    def generation(self, gen_id: str | None = None) -> Generation | None:
        """A generation's manifest (the current one by default); None when there is none."""
        gen_id = gen_id or self.current_id()
        if gen_id is None:
            return None
        return Generation.from_dict(self._read_json(f"generations/{gen_id}.json"))

    def generation_ids(self) -> list[str]:
        """Committed manifests, oldest first (ids sort by time)."""
        try:
            names = self.fs.ls(self._path("generations"), detail=False)
        except FileNotFoundError:
            return []
        return sorted(os.path.basename(n)[:-5] for n in names if n.endswith(".json"))

    def commit(self, gen: Generation) -> str:
        """Publish a generation: write its manifest, then switch ``current`` to it.

        Every object it lists must already be complete (checked); until the pointer moves the
        previous generation stays current.
        """
        if self.read_only:
            raise PermissionError(f"{self.url}: store opened read-only")
        for wdig in {_web_digest_of(w["key"]) for w in gen.webs}:
            self._load_shards(wdig)
        missing = [w["key"] for w in gen.webs if w["key"] not in self._webs]
        missing += [k for rates in gen.features.values() for k in set(rates.values()) if not self.has(k)]
        if missing:
            raise RuntimeError(f"refusing to commit generation {gen.id}: {len(missing)} objects missing, "
                               f"e.g. {missing[0]}")
        if not self.fs.exists(self._path("zarr.json")):
            zarr.open_group(store=self.zstore, mode="a")
        gen.completed = gen.completed or now_iso()
        self._write_json(f"generations/{gen.id}.json", gen.to_dict())
        self._write_json(POINTER, {"generation": gen.id, "committed": gen.completed})
        return gen.id

    def size_bytes(self) -> int:
        """Total bytes under the store root (all generations and objects)."""
        try:
            return int(self.fs.du(self.root, total=True))
        except FileNotFoundError:
            return 0

    def gc(self, keep: int = 3) -> list[str]:
        """Delete objects no kept generation lists (the ``keep`` newest plus the current one).

        Returns the deleted keys. Never run concurrently with an index run.
        """
        ids = self.generation_ids()
        cur = self.current_id()
        kept = set(ids[-keep:]) | ({cur} if cur else set())
        live: set[str] = set()
        for gid in kept:
            g = self.generation(gid)
            live |= {w["key"] for w in g.webs} | {grid_key(w["key"]) for w in g.webs}
            live |= {k for rates in g.features.values() for k in rates.values()}
        dropped: list[str] = []
        for top, depth in (("features", 3), ("grids", 3)):
            for key in self._leaf_keys(top, depth):
                if key not in live:
                    self.fs.rm(self._path(key), recursive=True)
                    dropped.append(key)
        for shard in self._leaf_keys(SHARDS, 2):  # a shard goes when none of its webs is live
            z = self._open(shard)
            keys = sorted(z.attrs.get("webs", {})) if z is not None else []
            if not live.intersection(keys):
                self.fs.rm(self._path(shard), recursive=True)
                dropped += keys
        self._webs.clear()
        self._shards.clear()
        for gid in set(ids) - kept:
            self.fs.rm(self._path(f"generations/{gid}.json"))
        return dropped

    def _leaf_keys(self, top: str, depth: int) -> list[str]:
        level = [top]
        for _ in range(depth):
            nxt = []
            for rel in level:
                try:
                    entries = self.fs.ls(self._path(rel), detail=True)
                except FileNotFoundError:
                    continue
                nxt += [f"{rel}/{os.path.basename(e['name'].rstrip('/'))}" for e in entries
                        if e["type"] == "directory"]
            level = nxt
        return level
