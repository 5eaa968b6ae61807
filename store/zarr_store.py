"""Zarr v3 persistence of features, web shards and grids (design §9).

Layout under the store root (a local folder or any fsspec URL)::

    zarr.json                                    root group
    features/<sha[:2]>/<sha>/<fdig>              one packed uint8 array per clip and feature
                                                 parameters: its (F_rate, P, 3) point clouds per
                                                 rate (r10, r20, r30 ..., design §3) and (P,) point
                                                 weights back to back, laid out in its attributes
    webs/shards/<wdig>/<shard id>                one packed uint8 array per written batch of webs,
                                                 its chunks in one Zarr v3 shard (one object):
                                                 the flat arrays of MatchWeb.to_arrays() (ragged
                                                 paths as values + offsets, KG04 §3.2) of each web
                                                 back to back; its attributes map every web key
                                                 (webs/<sha_a[:2]>/<sha_a>-<sha_b>/<wdig>, one
                                                 per ordered clip pair and web parameters) to its
                                                 byte range, array layout and attributes
    grids/...                                    full grids, only with matchweb.keep_grids
    generations/, current                        manifests (``store/generations.py``)

Keys come from ``store/keys.py``. An object is marked ``complete`` in its attributes only after
all its arrays are written; a half-written object is never seen as present. Every feature object
and every web records the SHA-256 of its uncompressed bytes (``checksum``, also listed in the
generation manifest); each read recomputes it, so a truncated, bit-flipped or deleted chunk
(which zarr would read back as zeros) raises :class:`StoreIntegrityError` naming the object
instead of returning wrong numbers. Webs are many and
small (zarr costs ~2 ms of CPU per array created), so a batch of webs shares one array (a shard)
and a web key is found through the index in the shards' attributes, listed once per store
instance and again when a key is not found.
"""

from __future__ import annotations

import atexit
import hashlib
import json
import os
import threading
import uuid
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

import fsspec
import numpy as np
import orjson
import zarr
from motionweb.store.gcpause import gc_paused
from motionweb.store.keys import SHARDS, feature_key, grid_key, rate_tag, web_digest_of
from motionweb.store.threads import IO_THREADS, map_in_threads
from motionweb.store.web import MatchWeb
from numcodecs import Blosc
from zarr.codecs import BloscCodec
from zarr.storage import FsspecStore, LocalStore, StorePath

try:  # zarr's own classes, to open an object from metadata already read (MotionStore._header)
    from zarr.core.array import AsyncArray
    from zarr.core.metadata import ArrayV3Metadata
except ImportError:  # a zarr that moved them: readers open shards with zarr.open (attributes and all)
    AsyncArray = ArrayV3Metadata = None

#: Blosc lz4 + byte shuffle: fastest writes and a better ratio on float32 (measured on this store)
COMPRESSORS = (BloscCodec(cname="lz4", clevel=5, shuffle="shuffle"),)
# zarr.json written compact, in this process: zarr indents it by default, which takes Python's
# pure-Python JSON encoder instead of its C one; a web shard's attributes index its ~2,000 webs
# (~1.5 MB of JSON), and the indented encoding cost ~0.2 s of each such batch (issue 25). Readers
# parse the JSON, so either layout reads the same; set once, so every worker writes the same bytes.
zarr.config.set({"json_indent": None})
#: decodes any Blosc frame (its header names the compressor and shuffle): a reader's direct path
_BLOSC = Blosc()
#: frames per chunk along the first axis of large arrays (2000-4000 rows wrote fastest when measured)
CHUNK_ROWS = 4096
#: bytes per chunk of a packed object (one chunk for most clips' features)
PACKED_CHUNK = 1 << 24
#: fsspec options of every remote store's filesystems (see :class:`MotionStore`)
REMOTE_OPTIONS = {"use_listings_cache": False}
#: bytes per chunk of a web shard (a web read decodes ~1-2 chunks, not the whole shard)
SHARD_CHUNK = 1 << 18
#: decompressed bytes a pass over a shard's webs takes at a time, per thread (:meth:`MotionStore._shard_pass`)
PASS_BYTES = 1 << 25


#: the async filesystems zarr reads and writes remote stores through, kept until exit (fsspec
#: caches them anyway: one per endpoint and options) so that :func:`_close_sessions` closes them
_ASYNC_FS: set = set()


def _close_sessions() -> None:
    """At exit, close the HTTP sessions of the remote stores' async filesystems (s3fs closes
    only those of its sync instances; an open one makes aiohttp log "Unclosed client session" at
    shutdown). Runs on zarr's event loop, before zarr's own exit handler stops it (registered
    after zarr's: exit handlers run last registered first). Never raises."""
    from zarr.core.sync import sync

    for fs in list(_ASYNC_FS):
        client = getattr(fs, "_s3creator", None)  # s3fs; other filesystems: nothing to close
        if client is None:
            continue
        try:
            sync(client.__aexit__(None, None, None), timeout=1)
        except Exception:  # noqa: BLE001, S110 - the process is ending: a session left open is only noise
            pass


atexit.register(_close_sessions)


def pack_arrays(arrays: dict[str, np.ndarray], start: int = 0,
                align: int = 1) -> tuple[list[np.ndarray], list[list[Any]], int]:
    """Byte views of arrays and their layout rows ``[name, dtype, shape, start, nbytes]``, and the
    end offset; ``align``: each array starts on a multiple of it (zero bytes between)."""
    layout, parts = [], []
    for name, value in arrays.items():
        a = np.ascontiguousarray(value)
        if pad := -start % align:
            parts.append(np.zeros(pad, np.uint8))
            start += pad
        layout.append([name, a.dtype.str, list(a.shape), start, a.nbytes])
        parts.append(a.view(np.uint8).reshape(-1))
        start += a.nbytes
    return parts, layout, start


def unpack_arrays(buf: np.ndarray, layout: list[list[Any]], base: int = 0, copy: bool = True) -> dict[str, np.ndarray]:
    """Inverse of :func:`pack_arrays` on ``buf`` holding the bytes from offset ``base`` on (``copy``:
    arrays of their own, else views of ``buf``)."""
    out = {name: buf[start - base:start - base + nbytes].view(np.dtype(dtype)).reshape(shape)
           for name, dtype, shape, start, nbytes in layout}
    return {k: v.copy() for k, v in out.items()} if copy else out


_SCRATCH = threading.local()


def _scratch(name: str, n: int) -> np.ndarray:
    """This thread's reusable uint8 buffer ``name``, at least ``n`` bytes (a view of ``n``)."""
    buf = getattr(_SCRATCH, name, None)
    if buf is None or len(buf) < n:
        buf = np.empty(max(n, 2 * len(buf) if buf is not None else n), np.uint8)
        setattr(_SCRATCH, name, buf)
    return buf[:n]


class StoreError(ValueError):
    """A store object that cannot be used: ``key`` names it, ``reason`` says why."""

    def __init__(self, url: str, key: str, reason: str):
        self.key, self.reason = key, reason
        super().__init__(f"{url}: object {key} {reason}")


class StoreIntegrityError(StoreError):
    """A stored object whose bytes are missing, undecodable or differ from their checksum."""


def checksum(parts: list[np.ndarray] | np.ndarray) -> str:
    """SHA-256 (hex) of the concatenated bytes of ``parts``."""
    h = hashlib.sha256()
    for p in parts if isinstance(parts, list) else [parts]:
        h.update(np.ascontiguousarray(p).data)
    return h.hexdigest()


def _plain_chunks(meta: dict[str, Any]) -> tuple[int, str] | None:
    """(bytes per chunk, chunk key separator) of a 1-D uint8 array whose chunks are plain files of
    Blosc frames (``codecs`` bytes then blosc, as :meth:`MotionStore._write_bytes` writes a packed
    object), from its ``zarr.json``; None for any other layout (read through zarr)."""
    try:
        codecs = [c.get("name") for c in meta["codecs"]]
        chunk = meta["chunk_grid"]["configuration"]["chunk_shape"]
        enc = meta.get("chunk_key_encoding", {})
        sep = enc.get("configuration", {}).get("separator", "/")
        if (meta.get("data_type") == "uint8" and len(meta.get("shape", [])) == 1 and codecs == ["bytes", "blosc"]
                and meta["chunk_grid"].get("name") == "regular" and len(chunk) == 1 and int(chunk[0]) > 0
                and enc.get("name", "default") == "default" and sep in ("/", ".")
                and meta.get("fill_value", 0) == 0 and not meta.get("storage_transformers")):
            return int(chunk[0]), sep
    except (KeyError, TypeError, AttributeError, ValueError, IndexError):
        pass
    return None


def load_json(raw: bytes) -> Any:
    """A ``zarr.json`` parsed, the collector paused (:mod:`.gcpause`): orjson (~1.5x json's speed),
    or json where orjson refuses the text (zarr writes a NaN or infinite attribute as JSON's
    ``NaN`` / ``Infinity`` extension, which json reads back). json's ValueError otherwise."""
    with gc_paused():
        try:
            return orjson.loads(raw)
        except orjson.JSONDecodeError:
            return json.loads(raw)


def now_iso() -> str:
    return datetime.now(UTC).isoformat(timespec="milliseconds")


def _hint_ok(key: str, shard: str) -> bool:
    """Whether ``shard`` (a generation's record of where web ``key`` is) names a shard folder of
    the key's digest: ``webs/shards/<digest>/<name>``, one plain name (a manifest names no other
    path)."""
    folder, _, name = shard.rpartition("/")
    return (folder == f"{SHARDS}/{web_digest_of(key)}" and bool(name) and not name.startswith(".")
            and "\\" not in name and name.isprintable())


def new_id() -> str:
    """Sortable, unique: UTC timestamp plus a random suffix (names generations and web shards)."""
    return datetime.now(UTC).strftime("%Y%m%dT%H%M%S%fZ") + "-" + uuid.uuid4().hex[:6]


@dataclass(slots=True)
class _ReaderShard:
    """A complete shard as a reader keeps it (:meth:`MotionStore._take_in_shard`): its name, its
    array opened without its attributes, and its web entries as compact JSON texts, entry ``i``
    being ``blob[ends[i]:ends[i + 1]]`` (``ends`` (entries + 1,))."""

    name: str
    array: zarr.Array
    blob: bytes
    ends: np.ndarray


class MotionStore:
    """A Zarr v3 store of features, webs and grids (design §9); manifests: ``store/generations.py``.

    ``url`` is a local folder or any fsspec URL (``memory://``, ``s3://``, ``file://`` ...).
    Instances are cheap and picklable by URL, so Dask workers open their own. A remote URL's
    filesystem takes its endpoint and credentials from its own configuration, never from here:
    for ``s3://`` (s3fs) the AWS environment (``AWS_ENDPOINT_URL_S3``, ``AWS_ACCESS_KEY_ID`` ...),
    which each process opening the store must have. On S3 nothing is renamed: every object, manifest
    and pointer is written by PUTs of whole objects (``tests/flows/test_s3_store.py`` checks this
    against moto's S3 emulator, which shows the API is used correctly, not S3's latency or
    consistency under load).
    """

    def __init__(self, url: str, read_only: bool = False):
        self.url = str(url)
        self.read_only = read_only
        self._local = "://" not in self.url or self.url.startswith("file://")
        if self._local:
            self.fs, self.root = fsspec.core.url_to_fs(self.url)
            if not read_only:
                os.makedirs(self.root, exist_ok=True)
            self.zstore = LocalStore(self.root, read_only=read_only)
        else:
            # No listing cache: objects are written through zarr's (async) filesystem instance and
            # by other processes, so a cached listing of this one would hide new shards and
            # manifests (s3fs caches every listing by default). Endpoint and credentials come from
            # the filesystem's own configuration (for s3://, the AWS environment: README).
            self.fs, self.root = fsspec.core.url_to_fs(self.url, **REMOTE_OPTIONS)
            self.zstore = FsspecStore.from_url(self.url, storage_options=dict(REMOTE_OPTIONS),
                                               read_only=read_only)
            _ASYNC_FS.add(self.zstore.fs)
        # web key -> (shard key, its entry), from the attributes of the complete shards seen so far
        self._webs: dict[str, tuple[str, dict[str, Any]]] = {}
        # complete shards seen so far, kept open: opening one parses its whole index of webs
        self._shards: dict[str, zarr.Array] = {}
        # read-only (a reader of a library of any size): web key -> (shard number, entry number)
        # of the newest complete shard holding it; per shard its name, its array opened without
        # its attributes, and its entries as one compact JSON text each in a bytes blob (see
        # _take_in_shard): O(webs) bytes in a few large buffers, no Python object per web
        self._key_entry: dict[str, tuple[int, int]] = {}
        self._reader_shards: list[_ReaderShard] = []
        self._seen_shards: dict[str, int] = {}  # shard name -> its number in _reader_shards
        self._bad_hints: set[str] = set()  # recorded shards that could not be taken in
        # a reader's local shards laid out as write_webs lays them out: (file, (inner chunk
        # bytes, chunks), the shard's index once read) (see _read_local)
        self._local_layouts: dict[str, tuple[str, tuple[int, int], np.ndarray | None]] = {}
        # complete objects' headers read so far (features, grids): key -> (array, attributes)
        self._headers: dict[str, tuple[zarr.Array | None, dict[str, Any]]] = {}
        # those of them on a local disk in plain chunk files: key -> (bytes per chunk, separator)
        self._plain: dict[str, tuple[int, str]] = {}

    def __reduce__(self):
        return (MotionStore, (self.url, self.read_only))

    def __repr__(self) -> str:
        return f"MotionStore({self.url!r})"

    # ---------------------------------------------------------------- objects
    def _open(self, key: str) -> zarr.Group | zarr.Array | None:
        """The group (features, grids) or packed array (webs) stored at ``key``, None if absent or
        its metadata is unreadable. Zarr v3 only (every object is): on an object store, opening
        without the format also probed for v2 metadata, 6 requests per object instead of 2."""
        try:
            return zarr.open(store=self.zstore, path=key, mode="r", zarr_format=3)
        except (FileNotFoundError, zarr.errors.NodeNotFoundError, KeyError, ValueError, TypeError):
            return None

    def _header(self, key: str) -> tuple[zarr.Array | None, dict[str, Any]] | None:
        """(the array, its attributes) of the object at ``key`` from one read of its ``zarr.json``
        (orjson; the array opened from that metadata without its attributes, None for a group),
        None when absent, unreadable or not completely written. zarr's own open parses the same
        file with json and builds its attributes, ~1 ms an object, several times an object in a
        rerun (plan, verify, manifest, gc: issue 25). A complete object's header is kept by this
        instance until it writes or deletes the object, or finds it damaged (:meth:`_forget`):
        another process rewrites an object only after a verification found it damaged."""
        if key in self._headers:
            return self._headers[key]
        try:
            raw = self.fs.cat_file(self.path(f"{key}/zarr.json"))
            meta = load_json(raw)
            attrs = meta.pop("attributes", {}) if isinstance(meta, dict) else None
            if not isinstance(attrs, dict) or not attrs.get("complete", False):
                return None
            if meta.get("node_type") != "array":
                z = None
            elif AsyncArray is not None:
                z = zarr.Array(AsyncArray(metadata=ArrayV3Metadata.from_dict(meta), store_path=StorePath(self.zstore, key)))
            else:
                z = self._open(key)
            if z is not None and self._local and (plain := _plain_chunks(meta)) is not None:
                self._plain[key] = plain
        except Exception:  # noqa: BLE001 - absent, or damaged metadata: not a complete object
            return None
        self._headers[key] = (z, attrs)
        return z, attrs

    def _forget(self, key: str) -> None:
        """Drop what this instance keeps of the object at ``key`` (and of any object under it)."""
        for k in [k for k in self._headers if k == key or k.startswith(key.rstrip("/") + "/")]:
            del self._headers[k]
            self._plain.pop(k, None)

    def has(self, key: str) -> bool:
        """True when the object (a web, or a features / grid group) exists and was completely written."""
        if key.startswith("webs/"):
            return self._web_entry(key) is not None
        return self._header(key) is not None

    def _write_packed(self, key: str, arrays: dict[str, np.ndarray], attrs: dict[str, Any]) -> None:
        """Write small arrays as ONE uint8 Zarr array (bytes concatenated, layout in attrs).

        A web is ~10 small arrays, a clip's features 4; zarr's per-array overhead (~2 ms of CPU
        per array created, plus one per write) dominates such objects, so one array each costs
        a fraction of a group of arrays. Marked complete last.
        """
        parts, layout, _ = pack_arrays(arrays)
        self._write_bytes(key, parts, PACKED_CHUNK, {**attrs, "layout": layout})

    def _write_bytes(self, key: str, parts: list[np.ndarray], chunk: int, attrs: dict[str, Any],
                     one_object: bool = False) -> zarr.Array:
        """One uint8 Zarr array of the concatenated ``parts``, marked complete after its data.

        ``one_object``: its chunks go into one Zarr v3 shard (one stored object beside its
        ``zarr.json``, the chunks still read one by one through the shard's index), so a store's
        object count grows with the batches written, not with their bytes (issue 25)."""
        self._forget(key)
        buf = np.concatenate(parts) if parts else np.zeros(0, np.uint8)
        inner = max(1, min(buf.size, chunk))
        shards = (max(inner, -(-buf.size // inner) * inner),) if one_object else None
        # the attributes are written once, with "complete", after the data: a shard's are the index
        # of its ~2,000 webs (~1.5 MB of JSON), which zarr encoded twice (create, then complete)
        z = zarr.create_array(self.zstore, name=key, shape=buf.shape, chunks=(inner,), shards=shards,
                              dtype=np.uint8, compressors=COMPRESSORS, overwrite=True)
        if buf.size:
            z[...] = buf
        z.update_attributes({**attrs, "checksum": checksum(buf), "written": now_iso(), "complete": True})
        return z

    def _read_packed(self, key: str) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        head = self._header(key)
        if head is None or head[0] is None:
            raise KeyError(f"{self.url}: no complete object {key!r}")
        z, attrs = head[0], dict(head[1])
        try:
            buf = self._read_plain(key, z.shape[0], attrs.get("checksum"))
            if buf is None:
                buf = self._read_range(z, key, 0, z.shape[0], attrs.get("checksum"))
            layout = attrs.pop("layout")
            return unpack_arrays(buf, layout), attrs
        except Exception:
            self._forget(key)  # damaged: read afresh once rewritten
            raise

    def _read_plain(self, key: str, nbytes: int, expected: str | None) -> np.ndarray | None:
        """A packed object on a local disk read from its chunk files without zarr (its async
        machinery costs ~1 ms an object; a rerun verifies every clip's features), None when it is
        not laid out so or cannot be read or checked so (the caller reads through zarr, which says
        why). A chunk file that is absent holds the fill value, as zarr reads it."""
        plain = self._plain.get(key)
        if plain is None:
            return None
        size, sep = plain
        out = np.zeros(nbytes, np.uint8)
        try:
            for c in range(-(-nbytes // size)):
                dest = out[c * size:(c + 1) * size]
                try:
                    with open(self.path(f"{key}/c{sep}{c}"), "rb") as fh:
                        comp = fh.read()
                except FileNotFoundError:
                    continue  # never written: the fill value
                if len(dest) == size:
                    _BLOSC.decode(comp, out=dest)
                else:
                    part = np.frombuffer(_BLOSC.decode(comp), np.uint8)
                    if len(part) < len(dest):
                        return None
                    dest[:] = part[:len(dest)]
        except (OSError, ValueError, RuntimeError):
            return None
        if expected is not None and checksum(out) != expected:
            return None
        return out

    def _read_range(self, z: zarr.Array, key: str, start: int, nbytes: int, expected: str | None) -> np.ndarray:
        """Bytes ``start:start+nbytes`` of a packed array, checked against their recorded checksum."""
        try:
            buf = np.asarray(z[start:start + nbytes]) if nbytes else np.zeros(0, np.uint8)
        except Exception as exc:  # noqa: BLE001 - any codec or I/O failure is damage to this object
            raise StoreIntegrityError(self.url, key, f"is unreadable ({type(exc).__name__}: {exc})") from None
        if expected is not None and checksum(buf) != expected:
            raise StoreIntegrityError(self.url, key, "is damaged (its bytes differ from their checksum)")
        return buf

    def recorded_checksum(self, key: str) -> str | None:
        """The checksum a feature object or web was written with (None: absent or written without)."""
        if key.startswith("webs/"):
            found = self._web_entry(key)
            return found[1].get("checksum") if found else None
        head = self._header(key)
        return head[1].get("checksum") if head is not None else None

    def verify(self, key: str, expected: str | None = None) -> str | None:
        """Why the object at ``key`` cannot be reused (missing, incomplete, unreadable, checksum
        differs from the recorded one or from ``expected``), None when it is sound. Reads it whole."""
        try:
            if key.startswith("webs/"):
                if self._web_entry(key) is None:
                    return "missing"
                self.read_web_arrays(key)
            elif key.startswith("features/"):
                self._read_packed(key)
            elif not self.has(key):
                return "missing"
        except KeyError:
            return "missing"
        except StoreIntegrityError as exc:
            return exc.reason
        recorded = self.recorded_checksum(key)
        if expected is not None and recorded != expected:
            return "checksum differs from the manifest's"
        return None

    def verify_webs(self, keys: Iterable[str], expected: Mapping[str, str] | None = None,
                    threads: int | None = None) -> dict[str, str | None]:
        """:meth:`verify` of many webs (``expected``: checksums by key), answers in the order of
        ``keys``: on a local disk each shard read in one pass in its order (:meth:`_shard_pass`,
        each chunk decompressed once, ~0.2 ms a web; :meth:`verify` reads one through zarr,
        ~1.5 ms), the shards shared among ``threads`` threads (default: one per core, at most 8;
        the reads, Blosc and SHA-256 release the GIL: a no-change rerun of the 1e6-frame store,
        18,411 webs and 32.6 GB, took 118 s with one thread, 77 s with two; ``bench.rerun``),
        a web that pass does not give (missing, damaged, an object store) verified alone, which
        says why. O(bytes of the webs) / threads."""
        expected = expected or {}
        keys = list(keys)
        local, _ = self._by_shard(keys)  # the others are verified alone below

        def shard_ok(item: tuple[str, list[tuple[int, str, dict[str, Any]]]]) -> list[tuple[str, bool]]:
            return [(key, buf is not None and (key not in expected or expected[key] == e.get("checksum")))
                    for key, e, buf in self._shard_pass(*item)]

        passed = dict(kv for part in map_in_threads(shard_ok, list(local.items()), threads, IO_THREADS, "verify")
                      for kv in part)
        out: dict[str, str | None] = {}
        for key in keys:
            out[key] = None if passed.get(key) else self.verify(key, expected.get(key))
        return out

    def _write_group(self, key: str, arrays: dict[str, np.ndarray], attrs: dict[str, Any]) -> None:
        """Write arrays into a fresh group; mark it complete last (a crash leaves it incomplete)."""
        self._forget(key)
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

    # motion spaces (KG04 §4): content-addressed, outside generations (gc keeps them)
    def write_space(self, digest: str, arrays: dict[str, np.ndarray], attrs: dict[str, Any]) -> str:
        """Store a motion space's arrays and attributes under ``spaces/<digest>``; returns the key."""
        key = f"spaces/{digest}"
        self._write_group(key, arrays, attrs)
        return key

    def read_space(self, space_id: str) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """A stored motion space by its digest (or a unique prefix of it); KeyError naming it."""
        ids = [i for i in self.space_ids() if i.startswith(space_id)] if space_id else []
        if len(ids) != 1:
            what = "is ambiguous" if ids else "is not stored"
            raise KeyError(f"motion space {space_id!r} {what} in {self.url} ({len(self.space_ids())} stored)")
        return self._read_group(f"spaces/{ids[0]}")

    def space_ids(self) -> list[str]:
        """Digests of the completely written motion spaces."""
        return sorted(k.split("/", 1)[1] for k in self.leaf_keys("spaces", 1) if self.has(k))

    # features
    def has_features(self, sha: str, fdigest: str, rates: list[float]) -> bool:
        head = self._header(feature_key(sha, fdigest))
        if head is None:
            return False
        have = {entry[0] for entry in head[1].get("layout", [])}
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
    def write_webs(self, webs: list[tuple[str, dict[str, np.ndarray], dict[str, Any]]]) -> dict[str, str]:
        """Store webs ``(key, flat arrays of MatchWeb.to_arrays(), attributes)`` as one shard per
        web parameter digest: one Zarr array for the whole batch, O(1) Zarr calls per batch.
        Returns the shard of each key (a generation records it: a reader takes in only the shards
        its webs are in, see :meth:`web_shard`)."""
        by_digest: dict[str, list[tuple[str, dict[str, np.ndarray], dict[str, Any]]]] = {}
        for item in webs:
            by_digest.setdefault(web_digest_of(item[0]), []).append(item)
        written: dict[str, str] = {}
        for wdig, items in by_digest.items():
            parts, entries, start = [], {}, 0
            for key, arrays, attrs in items:
                p, layout, end = pack_arrays(arrays, start)
                parts += p
                entries[key] = {"start": start, "nbytes": end - start, "layout": layout, "attrs": attrs,
                                "checksum": checksum(p)}
                start = end
            shard = f"{SHARDS}/{wdig}/{new_id()}"
            self._shards[shard] = self._write_bytes(shard, parts, SHARD_CHUNK, {"webs": entries}, one_object=True)
            self._webs.update({key: (shard, e) for key, e in entries.items()})
            written.update(dict.fromkeys(entries, shard))
        return written

    def write_web(self, key: str, arrays: dict[str, np.ndarray], attrs: dict[str, Any] | None = None) -> None:
        """Store one web's flat arrays (``MatchWeb.to_arrays()``) under ``key``."""
        self.write_webs([(key, arrays, attrs or {})])

    def _web_entry(self, key: str, hint: str | None = None) -> tuple[str, dict[str, Any]] | None:
        """(shard, entry) of a web key; lists the digest's shards again when the key is unknown.
        ``hint`` (a reader): the shard a generation recorded for the key (``write_webs``), taken
        in alone first, so that a reader takes in the shards its webs are in, not every shard of
        the store (about 70 ms per 2,000-web shard); a hint that is not a shard of the key's
        digest, or does not hold the key (gone, damaged), is ignored."""
        if self.read_only:
            if (key not in self._key_entry and hint and hint not in self._seen_shards
                    and hint not in self._bad_hints and _hint_ok(key, hint) and not self._take_in_shard(hint)):
                self._bad_hints.add(hint)
            if key not in self._key_entry:
                self._load_shards(web_digest_of(key))
            found = self._key_entry.get(key)
            if found is None:
                return None
            rs = self._reader_shards[found[0]]
            return rs.name, orjson.loads(rs.blob[rs.ends[found[1]]:rs.ends[found[1] + 1]])
        if key not in self._webs:
            self._load_shards(web_digest_of(key))
        return self._webs.get(key)

    def _shard(self, shard: str) -> zarr.Array | None:
        """A complete shard's array (a reader's opened without its attributes)."""
        if self.read_only and shard in self._seen_shards:
            return self._reader_shards[self._seen_shards[shard]].array
        return self._shards.get(shard) or self._open(shard)

    def _shard_header(self, shard: str) -> tuple[zarr.Array, dict[str, Any]] | None:
        """(its array, its index of webs by key) of a complete shard (:meth:`_header`, not kept
        there: the caller keeps the entries its own way), None when it is not complete (being
        written, its writer died, or damaged: its webs are not seen)."""
        head = self._header(shard)
        self._headers.pop(shard, None)
        if head is None or head[0] is None or not isinstance(head[1].get("webs"), dict):
            return None
        return head[0], head[1]["webs"]

    def _take_in_shard(self, shard: str) -> bool:
        """A reader takes in a shard: its zarr.json read once (:meth:`_shard_header`), each web
        entry kept as compact JSON in one blob (about 0.9 kB a web; a parsed entry is several
        times that). False when the shard is not complete. Cost O(its webs)."""
        found = self._shard_header(shard)
        if found is None:
            return False
        z, webs = found
        try:
            texts = [orjson.dumps(e) for e in webs.values()]  # compact, ~4x json's speed
        except Exception:  # noqa: BLE001 - a damaged shard header: its webs are missing
            return False
        n = len(self._reader_shards)
        ends = np.zeros(len(texts) + 1, np.int64)
        np.cumsum([len(t) for t in texts], out=ends[1:])
        self._reader_shards.append(_ReaderShard(shard, z, b"".join(texts), ends))
        self._key_entry.update({k: (n, i) for i, k in enumerate(webs)})
        self._seen_shards[shard] = n
        self._note_layout(shard, z.metadata.to_dict())
        return True

    def _note_layout(self, shard: str, meta: dict[str, Any]) -> None:
        """Remember a local shard's file and inner chunks when its metadata (``zarr.json``, without
        the attributes) is laid out as :meth:`write_webs` lays it out, for :meth:`_read_local`."""
        if self._local and meta.get("codecs") and meta["codecs"][0].get("name") == "sharding_indexed":
            cfg = meta["codecs"][0].get("configuration", {})
            outer = meta.get("chunk_grid", {}).get("configuration", {}).get("chunk_shape", [0])[0]
            inner = cfg.get("chunk_shape", [0])[0]
            if (cfg.get("index_location", "end") == "end" and meta.get("data_type") == "uint8"
                    and [c.get("name") for c in cfg.get("codecs", [])] == ["bytes", "blosc"]
                    and [c.get("name") for c in cfg.get("index_codecs", [])] == ["bytes", "crc32c"]
                    and cfg["index_codecs"][0].get("configuration", {}).get("endian", "little") == "little"
                    and inner > 0 and outer >= meta["shape"][0] and outer % inner == 0):
                sep = meta.get("chunk_key_encoding", {}).get("configuration", {}).get("separator", "/")
                self._local_layouts[shard] = (os.path.join(self.path(shard), f"c{sep}0"), (inner, outer // inner), None)

    def _load_shards(self, wdig: str) -> None:
        """Take in the complete shards of web digest ``wdig`` not seen yet (one listing; each new
        shard's index of webs read). A reader keeps of each only its keys (O(webs) keys in all)
        and the last few shards open."""
        try:
            entries = self.fs.ls(self.path(f"{SHARDS}/{wdig}"), detail=True)
        except FileNotFoundError:
            return
        seen = self._shards if not self.read_only else self._seen_shards
        # a writer keeps O(webs) parsed entries: out of the collector's reach once in (store/gcpause.py);
        # a reader (a long-lived service) keeps them compact and freezes nothing
        with gc_paused(keep=not self.read_only):
            self._take_in_shards(wdig, entries, seen)

    def _take_in_shards(self, wdig: str, entries: list[dict[str, Any]], seen: Mapping[str, Any]) -> None:
        """The shards of the listing ``entries`` not in ``seen``, taken in (see :meth:`_load_shards`)."""
        for name in sorted(e["name"] for e in entries if e["type"] == "directory"):
            shard = f"{SHARDS}/{wdig}/{os.path.basename(name.rstrip('/'))}"
            if shard in seen:
                continue
            if self.read_only:
                self._take_in_shard(shard)
                continue
            found = self._shard_header(shard)
            if found is None:
                continue
            z = self._shards[shard] = found[0]
            self._webs.update({key: (shard, e) for key, e in found[1].items()})
            if self._local:  # a writer verifying many webs reads them as a reader does (verify_webs)
                self._note_layout(shard, z.metadata.to_dict())

    def web_shard(self, key: str, hint: str | None = None) -> str | None:
        """The shard that serves a web key (the newest complete one holding it; for a reader, the
        ``hint`` when it holds the key, see :meth:`_web_entry`), None if none."""
        found = self._web_entry(key, hint)
        return found[0] if found else None

    def web_keys(self, wdig: str) -> set[str]:
        """Every completely written web key with parameter digest ``wdig`` (one shard listing)."""
        self._load_shards(wdig)
        return {k for k in (self._key_entry if self.read_only else self._webs) if web_digest_of(k) == wdig}

    def web_attrs(self, key: str) -> dict[str, Any]:
        """The attributes a web was written with ({} when absent)."""
        found = self._web_entry(key)
        return dict(found[1]["attrs"]) if found else {}

    def read_web_arrays(self, key: str, shard: str | None = None) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """The flat arrays of a web (names, dtypes and shapes as written) and its attributes
        (``shard``: the generation's record of where it is, a hint, see :meth:`_web_entry`)."""
        found = self._web_entry(key, shard)
        z = self._shard(found[0]) if found else None
        if z is None:
            raise KeyError(f"{self.url}: no complete web {key!r}")
        e = found[1]
        buf = self._read_local(found[0], e["start"], e["nbytes"])
        if buf is None or (e.get("checksum") is not None and checksum(buf) != e["checksum"]):
            buf = self._read_range(z, key, e["start"], e["nbytes"], e.get("checksum"))  # zarr tells what is wrong
        return unpack_arrays(buf, e["layout"], e["start"]), dict(e["attrs"])

    def iter_web_arrays(self, keys: Iterable[str], shards: Mapping[str, str | None] | None = None
                        ) -> Iterator[tuple[str, dict[str, np.ndarray] | None]]:
        """``(key, flat arrays)`` of each web of ``keys`` on local shards, checked
        against its checksum, in the order the store holds them: by shard, then by offset, so
        that each inner chunk of a shard is decompressed once per pass (a 256 kB chunk holds
        several webs; read one by one, each web decompressed its chunks again). ``(key, None)``
        for a web not read so (missing, on an object store, or its bytes differ from their
        checksum): the caller reads it alone (:meth:`read_web_arrays`, which names what is
        wrong), first. ``shards``: the generation's record of each key's shard (hints, see
        :meth:`_web_entry`). O(bytes of the webs)."""
        local, alone = self._by_shard(keys, shards)
        for key in alone:
            yield key, None
        for shard, items in local.items():
            for key, e, buf in self._shard_pass(shard, items):
                yield key, None if buf is None else unpack_arrays(buf, e["layout"], e["start"])

    def map_web_arrays(self, keys: Iterable[str], fn: Callable[[dict[str, np.ndarray]], Any],
                       shards: Mapping[str, str | None] | None = None, threads: int | None = None
                       ) -> tuple[dict[str, Any], list[str]]:
        """:meth:`iter_web_arrays` with the shards shared among ``threads`` threads (default: one
        per core, at most ``IO_THREADS``; the reads, Blosc and SHA-256 release the GIL), for a pass
        whose answer per web is small (e.g. its path values for a quantile): ``fn(flat arrays)`` of
        each web checked against its checksum, called in the reading thread on arrays valid during
        the call only. Returns (``fn``'s answer by key, the keys not read so: missing, damaged or
        on an object store, for the caller to read alone, first). O(bytes of the webs) / threads."""
        local, alone = self._by_shard(keys, shards)

        def part(item: tuple[str, list[tuple[int, str, dict[str, Any]]]]) -> list[tuple[str, bool, Any]]:
            return [(key, buf is not None,
                     None if buf is None else fn(unpack_arrays(buf, e["layout"], e["start"], copy=False)))
                    for key, e, buf in self._shard_pass(*item)]

        out: dict[str, Any] = {}
        for piece in map_in_threads(part, list(local.items()), threads, IO_THREADS, "webs"):
            for key, ok, value in piece:
                if ok:
                    out[key] = value
                else:
                    alone.append(key)
        return out, alone

    def _by_shard(self, keys: Iterable[str], shards: Mapping[str, str | None] | None = None
                  ) -> tuple[dict[str, list[tuple[int, str, dict[str, Any]]]], list[str]]:
        """The webs of ``keys`` on local shards laid out for :meth:`_read_local`, by shard:
        ``(start, key, entry)`` each; and the other keys (missing, on an object store), in order."""
        local: dict[str, list[tuple[int, str, dict[str, Any]]]] = {}
        alone: list[str] = []
        shards = shards or {}
        for key in keys:
            found = self._web_entry(key, shards.get(key)) if self._local else None
            if found is None or found[0] not in self._local_layouts:
                alone.append(key)
            else:
                local.setdefault(found[0], []).append((found[1]["start"], key, found[1]))
        return local, alone

    def _shard_pass(self, shard: str, items: list[tuple[int, str, dict[str, Any]]]
                    ) -> Iterator[tuple[str, dict[str, Any], np.ndarray | None]]:
        """``(key, entry, bytes)`` of the webs ``items`` of one local shard in increasing offset;
        the bytes are None when they cannot be read or differ from the entry's checksum, else a
        view of this thread's scratch buffer, valid until the next. The webs are taken in runs of
        up to :data:`PASS_BYTES` (a larger web alone): a run's inner chunks read in one file
        read where they lie back to back, each decompressed once, the webs then sliced from them.
        Per web that leaves its checksum and a slice: reading web by web (a file opened, a chunk
        or two read and decompressed) cost 7.2 s of the 381k store's no-change rerun."""
        order = sorted(items, key=lambda t: t[0])
        i = 0
        while i < len(order):
            lo = order[i][0]
            j, hi = i, lo
            while j < len(order) and (j == i or order[j][0] + order[j][2]["nbytes"] - lo <= PASS_BYTES):
                hi = max(hi, order[j][0] + order[j][2]["nbytes"])
                j += 1
            span = self._read_local(shard, lo, hi - lo) if hi > lo else np.zeros(0, np.uint8)
            for start, key, e in order[i:j]:
                buf = None if span is None else span[start - lo:start - lo + e["nbytes"]]
                ok = (buf is not None and len(buf) == e["nbytes"]
                      and (e.get("checksum") is None or checksum(buf) == e["checksum"]))
                yield key, e, buf if ok else None
            i = j

    def _read_local(self, shard: str, start: int, nbytes: int) -> np.ndarray | None:
        """Bytes ``start:start+nbytes`` of a shard on a local disk, read from its one file
        without zarr: the inner chunks they span located by the shard's index (read once per
        shard: (offset, nbytes) little-endian uint64 per chunk, at the end of the file, as the
        Zarr v3 sharding codec lays it out), read in one file read where they lie back to back
        (as :meth:`write_webs` writes them), and each decompressed (Blosc). A web read is then
        one file read and a chunk or two decompressed (zarr's path costs ~1 ms more per read in
        its asynchronous machinery). None when the shard is not laid out so (another codec
        chain, an object store) or the bytes cannot be had: the caller reads through zarr, which
        checks. The bytes are a view of this thread's scratch buffers (no allocation per read,
        which fragmented the heap by gigabytes over a day of searches): valid until its next read."""
        layout = self._local_layouts.get(shard) if self._local else None
        if layout is None:
            return None
        path, inner, index = layout
        try:
            if index is None:
                with open(path, "rb") as fh:
                    fh.seek(-(16 * inner[1] + 4), os.SEEK_END)
                    raw = fh.read(16 * inner[1])
                index = np.frombuffer(raw, "<u8").reshape(inner[1], 2)
                self._local_layouts[shard] = (path, inner, index)
            size = inner[0]
            first, last = start // size, (start + nbytes - 1) // size
            flat = _scratch("chunks", (last - first + 1) * size)
            rows = index[first:last + 1]
            written = rows[:, 0] != 2**64 - 1
            offs, lens = rows[written, 0].astype(np.int64), rows[written, 1].astype(np.int64)
            together = len(offs) > 0 and bool(np.all(offs[1:] == offs[:-1] + lens[:-1]))
            with open(path, "rb") as fh:
                if together:  # one read of the run's compressed chunks
                    comp_all = _scratch("compressed", int(lens.sum()))
                    fh.seek(int(offs[0]))
                    if fh.readinto(comp_all) != len(comp_all):
                        return None
                k = pos = 0
                for i, c in enumerate(range(first, last + 1)):
                    dest = flat[i * size:(i + 1) * size]
                    if not written[i]:
                        dest[:] = 0  # never written: the fill value
                        continue
                    n = int(lens[k])
                    if together:
                        comp = comp_all[pos:pos + n]
                        pos += n
                    else:
                        fh.seek(int(offs[k]))
                        comp = _scratch("compressed", n)
                        if fh.readinto(comp) != n:
                            return None
                    k += 1
                    _BLOSC.decode(comp, out=dest)
            lo = start - first * size
            out = flat[lo:lo + nbytes]
            return out if len(out) == nbytes else None
        except (OSError, ValueError, RuntimeError, IndexError):
            return None

    def read_web(self, key: str, shard: str | None = None) -> MatchWeb:
        """The stored web as a ``tasks.matchweb.MatchWeb`` (``shard``: see :meth:`read_web_arrays`)."""
        arrays, _ = self.read_web_arrays(key, shard)
        return MatchWeb.from_arrays(arrays)

    def write_grid(self, web: str, grid: np.ndarray) -> None:
        """Keep a full distance grid next to a web (``matchweb.keep_grids``; plots, debugging)."""
        self._write_group(grid_key(web), {"grid": grid}, {"web": web})

    def read_grid(self, web: str) -> np.ndarray:
        return self._read_group(grid_key(web), ["grid"])[0]["grid"]

    # ----------------------------------------------------------- plain files
    def path(self, rel: str) -> str:
        """The filesystem path (for ``self.fs``) of a key relative to the store root."""
        return f"{self.root.rstrip('/')}/{rel}"

    def write_json(self, rel: str, data: Any, atomic: bool = True) -> None:
        """Write a JSON file; on local disks by rename of a temp file (atomic), elsewhere by one put.
        One line, keys sorted: an indented dump takes Python's pure-Python encoder, ~3x the time
        of the C one (3.05 s against 1.12 s for the 146,610-web manifest of issue 25)."""
        payload = json.dumps(data, sort_keys=True, default=str).encode()
        path = self.path(rel)
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

    def read_json(self, rel: str) -> Any:
        return json.loads(self.fs.cat_file(self.path(rel)))

    def ensure_root(self) -> None:
        """Create the root Zarr group if the store has none yet."""
        if not self.fs.exists(self.path("zarr.json")):
            zarr.open_group(store=self.zstore, mode="a")

    def size_bytes(self) -> int:
        """Total bytes under the store root (all generations and objects)."""
        try:
            return int(self.fs.du(self.root, total=True))
        except FileNotFoundError:
            return 0

    # ------------------------------------------------------------- listing
    def leaf_keys(self, top: str, depth: int) -> list[str]:
        """Keys ``depth`` folder levels below ``top`` (e.g. ``features``, 3: every features object)."""
        level = [top]
        for _ in range(depth):
            nxt = []
            for rel in level:
                try:
                    entries = self.fs.ls(self.path(rel), detail=True)
                except FileNotFoundError:
                    continue
                nxt += [f"{rel}/{os.path.basename(e['name'].rstrip('/'))}" for e in entries
                        if e["type"] == "directory"]
            level = nxt
        return level

    def shard_web_keys(self, shard: str) -> list[str]:
        """The web keys a shard holds ([] when it is unreadable or was never completed)."""
        z = self._open(shard)
        return sorted(z.attrs.get("webs", {})) if z is not None else []

    def delete(self, key: str) -> None:
        """Remove an object (a folder of the store) and forget the shards and webs seen so far."""
        self.fs.rm(self.path(key), recursive=True)
        self._forget(key)
        self._webs.clear()
        self._shards.clear()
