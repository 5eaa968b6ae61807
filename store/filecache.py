"""A bounded, content-keyed cache of flat arrays in files on a local disk, shared by processes and
runs (issue 25, part 5: search at scale).

The service packs each clip's webs into a walk graph when a search first reaches the clip
(``tasks.search.MatchSearch``): on the 381k-frame demo store about 36 ms to read a clip's 180 webs
and 10 ms to pack them, against 2 ms to read the packed graph back from a file (1.2 MB compressed
of 4.8 MB). A search that reaches a whole dense category touches ~180 graphs, far more than a
search worker's memory cache holds, so the packed graphs are kept here too: the page cache of the
operating system keeps the hot files in memory without counting against the service's own.

Keys are content keys (hex SHA-256 of what the value is computed from, e.g. the keys of the webs a
graph packs): a file is never stale, so the cache is shared by every generation and store, and
safe to delete at any time. Each file is written whole to a temporary name and renamed (readers
never see a partial file) and holds a CRC-32 of its payload: a damaged file reads as missing and
is removed. The folder is bounded by bytes: past ``max_bytes`` the least recently used files
(by modification time, refreshed on each read) are removed down to 80% of the bound.

File layout: ``MAGIC``, an 8-byte little-endian header length, a JSON header (the arrays' layout
as ``store.zarr_store`` packs a web, the caller's metadata, the payload's size and CRC-32, the
codec), then the payload: the arrays' bytes compressed with Blosc (LZ4, byte shuffle), or, for a
value put ``raw`` (the walk graphs), the arrays as they lie in memory, the payload starting on a
page and each array on a 64-byte boundary, so that :meth:`FileCache.open_mapped` can map the file
and hand out views of it.

Mapped values (:meth:`FileCache.open_mapped`): a graph of a long take is hundreds of MB (29 M
states, 600 MB, on the million-frame store) while a query of rows a..b walks only the states of
those rows (a graph's states are sorted by web, row, column). Reading such a graph back whole cost
2–3 s (read, LZ4, copies to align) each time a search worker's memory cache had dropped it; mapped,
a file is read once per process to check it (CRC-32 and the caller's own check, ~0.5 s for that
graph), its pages then released, and each later walk brings in only the pages of its rows — from
the operating system's page cache, which is not the service's memory and is reclaimed under
pressure. A process keeps the mappings it opened in an LRU bounded by half the cache's bound (file
bytes). A file removed from the folder while still mapped keeps its disk blocks until it is
dropped: :meth:`FileCache.release` with ``sweep`` (after each request of a search worker) drops
the mappings whose files are gone, so the disk held is the bound, plus at most half of it per process that
idles with mappings of removed files (measured the hard way: a first search on the million-frame
store wrote 23 GB of graph files in 12 min with a 24 GB bound and a mapping bound as large, and
the disk filled past the bound by about 9 GB of removed files still mapped). Each mapping also
holds a file descriptor (Python's ``mmap`` keeps a duplicate of the file's), so the LRU is bounded
in entries too, by a quarter of the process's limit on open files (:func:`mapping_slots`): the
small graphs of a library of many short clips (~1-5 MB each) would otherwise exhaust a default
limit of 1024 long before the bytes bound, and every read of the store would then fail.
"""

from __future__ import annotations

import json
import logging
import mmap
import os
import resource
import threading
import uuid
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from motionweb.store.cache import LRU
from motionweb.store.zarr_store import pack_arrays, unpack_arrays
from numcodecs import Blosc

__all__ = ["FileCache", "default_folder", "mapping_slots"]

T = TypeVar("T")

log = logging.getLogger(__name__)

MAGIC = b"MWFC1\n"
#: Blosc compresses one buffer of at most 2 GB; a larger value is not kept
MAX_VALUE_BYTES = 2**31 - 2**20
_CODEC = Blosc(cname="lz4", clevel=5, shuffle=Blosc.SHUFFLE)
#: a raw payload starts on a page (the offset of a mapping's views) and each array on 64 bytes
_PAGE, _ALIGN = 4096, 64
#: bytes read at a time to check a raw file's CRC-32 before it is mapped
_CRC_CHUNK = 16 << 20


#: environment variable naming the folder of motionweb's file caches (default: the user's cache folder)
CACHE_ENV = "MOTIONWEB_CACHE_DIR"


def default_folder(kind: str = "graphs") -> Path:
    """``$MOTIONWEB_CACHE_DIR/<kind>``, else ``$XDG_CACHE_HOME/motionweb/<kind>`` (``~/.cache`` without it)."""
    if os.environ.get(CACHE_ENV):
        return Path(os.environ[CACHE_ENV]) / kind
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "motionweb" / kind


def _release(mm: mmap.mmap) -> None:
    """Drop ``mm``'s resident pages (a copy-on-write mapping never written: they are the file's)."""
    try:
        mm.madvise(mmap.MADV_DONTNEED)
    except (AttributeError, ValueError, OSError):  # no madvise here, or a mapping already closed
        pass


def _is_key(key: str) -> bool:
    return 8 <= len(key) <= 128 and all(c in "0123456789abcdef" for c in key)


def mapping_slots() -> int:
    """How many mappings a process keeps open (each holds a file descriptor): a quarter of its
    soft limit on open files, at least 16. A process that may hold many (a search worker) raises
    its soft limit first (``flows.app.worker``)."""
    soft, _ = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft == resource.RLIM_INFINITY:
        soft = 1 << 16
    return max(16, int(soft) // 4)


class FileCache:
    """Values ``(arrays, meta)`` under hex content keys in ``folder``, at most ``max_bytes`` of
    files (see the module notes). Thread- and process-safe: writes are atomic renames; an
    eviction that races another process's read makes that read a miss."""

    def __init__(self, folder: str | os.PathLike[str], max_bytes: int):
        if max_bytes <= 0:
            raise ValueError(f"a file cache needs a positive bound, got {max_bytes} bytes")
        self.folder, self.max_bytes = Path(folder), int(max_bytes)
        self._lock = threading.Lock()
        self._bytes: int | None = None  # this process's estimate of the folder's bytes (scanned once)
        self.hits = self.misses = self.writes = self.damaged = 0
        #: the values this process opened mapped, by key, with their mapping, charged their file's
        #: bytes: at most half the bound (see the module notes)
        self._mapped = LRU(max_bytes=self.max_bytes // 2, max_items=mapping_slots())
        self._used: dict[str, mmap.mmap] = {}  # mappings handed out since the last :meth:`release`

    def _path(self, key: str) -> Path:
        if not _is_key(key):
            raise ValueError(f"a file cache key is a lowercase hex digest, got {key!r}")
        return self.folder / key[:2] / f"{key}.mwc"

    def get(self, key: str) -> tuple[dict[str, np.ndarray], dict[str, Any]] | None:
        """The arrays and metadata kept under ``key`` (arrays of their own, whatever the codec), or
        None (missing, damaged or unreadable; a damaged file is removed)."""
        path = self._path(key)
        try:
            raw = path.read_bytes()
        except OSError:
            self.misses += 1
            return None
        try:
            value = self._decode(raw)
        except (ValueError, KeyError, TypeError, RuntimeError) as exc:
            self._damaged(path, exc)
            return None
        self._touch(path)
        self.hits += 1
        return value

    def _damaged(self, path: Path, exc: BaseException) -> None:
        self.damaged += 1
        self.misses += 1
        log.warning("%s: damaged cache file removed (%s)", path, exc)
        path.unlink(missing_ok=True)

    @staticmethod
    def _touch(path: Path) -> None:
        try:
            os.utime(path)  # recently used: evicted last
        except OSError:
            pass

    @staticmethod
    def _header(raw: bytes | memoryview, size: int) -> tuple[dict[str, Any], int]:
        """(JSON header, payload offset) of a cache file of ``size`` bytes whose first bytes are
        ``raw`` (at least the header's); ValueError for a file that is not one or whose payload
        is not all there."""
        if bytes(raw[:len(MAGIC)]) != MAGIC or len(raw) < len(MAGIC) + 8:
            raise ValueError("not a cache file")
        n = int.from_bytes(raw[len(MAGIC):len(MAGIC) + 8], "little")
        start = len(MAGIC) + 8 + n
        if len(raw) < start:
            raise ValueError("its header is cut short")
        header = json.loads(bytes(raw[len(MAGIC) + 8:start]))
        if header.get("codec", "blosc") == "raw":
            start = -(-start // _PAGE) * _PAGE
        if size - start != header["compressed"]:
            raise ValueError("its payload is not the size its header gives")
        return header, start

    @classmethod
    def _decode(cls, raw: bytes) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        header, start = cls._header(raw, len(raw))
        payload = memoryview(raw)[start:]
        if zlib.crc32(payload) != header["crc32"]:
            raise ValueError("its payload does not match its checksum")
        buf = np.empty(header["nbytes"], np.uint8)
        if header.get("codec", "blosc") == "raw":
            buf[:] = np.frombuffer(payload, np.uint8)
        elif header["nbytes"]:
            _CODEC.decode(payload, out=buf)
        return unpack_arrays(buf, header["layout"], copy=False), header["meta"]

    def put(self, key: str, arrays: dict[str, np.ndarray], meta: dict[str, Any], raw: bool = False) -> bool:
        """Keep ``arrays`` (flat numeric arrays) and ``meta`` (JSON) under ``key``; False when it
        was not kept (too large, or the folder cannot be written: a cache never fails its
        caller). ``raw``: uncompressed and aligned, for :meth:`open_mapped` (written straight
        from the arrays, no copy)."""
        path = self._path(key)
        if raw:
            parts, layout, nbytes = pack_arrays(arrays, align=_ALIGN)
            if nbytes > self.max_bytes:
                return False
            crc = 0
            for part in parts:
                crc = zlib.crc32(part, crc)
            size = nbytes
        else:
            parts, layout, nbytes = pack_arrays(arrays)
            if nbytes > MAX_VALUE_BYTES:
                return False
            parts = [_CODEC.encode(np.concatenate(parts))] if nbytes else []
            size = len(parts[0]) if parts else 0
            crc = zlib.crc32(parts[0]) if parts else 0
        header = json.dumps({"layout": layout, "meta": meta, "nbytes": nbytes, "compressed": size,
                             "crc32": crc, "codec": "raw" if raw else "blosc"}).encode()
        head = MAGIC + len(header).to_bytes(8, "little") + header
        if raw:
            head += b"\0" * (-len(head) % _PAGE)
        tmp = path.with_name(f"{path.name}.tmp-{uuid.uuid4().hex[:8]}")
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            with open(tmp, "wb") as fh:
                fh.write(head)
                for part in parts:
                    fh.write(part)
            os.replace(tmp, path)
        except OSError as exc:
            log.debug("%s: not kept (%s)", path, exc)
            try:
                tmp.unlink(missing_ok=True)
            except OSError:
                pass
            return False
        self.writes += 1
        with self._lock:
            self._bytes = (self._scan()[0] if self._bytes is None else self._bytes + len(head) + size)
            over = self._bytes > self.max_bytes
        if over:
            self.trim()
        return True

    def open_mapped(self, key: str, opener: Callable[[dict[str, np.ndarray], dict[str, Any]], T],
                    count: bool = True) -> T | None:
        """``opener(arrays, meta)`` of the raw file kept under ``key``, its arrays views of the file
        mapped copy-on-write (writable, never written back; the opener must not write them), or
        None (missing, not raw, damaged — then removed — or refused by the opener, which raises
        ValueError, KeyError or TypeError: it stays, for the caller to replace).

        The value is kept in this process's LRU of mapped values (bounded by half the cache's
        bound, charged its file's bytes): a later call returns it without touching the file beyond its
        use time. The first call reads the file once to check its CRC-32, maps it, calls the
        opener (which may read every page, e.g. to check the arrays) and then releases the
        pages it touched (``MADV_DONTNEED``): only pages a caller reads later are resident.
        ``count``: a disk open counts as a hit (False for a file this process just wrote)."""
        path = self._path(key)
        kept = self._mapped.get(key)
        if kept is not None:
            self._touch(path)
            with self._lock:
                self._used[key] = kept[1]
            return kept[0]
        try:
            with open(path, "rb") as fh:
                mapped = self._map(fh)
        except OSError:
            self.misses += 1
            return None
        except (ValueError, KeyError, TypeError) as exc:
            self._damaged(path, exc)
            return None
        if mapped is None:  # not a raw file (e.g. kept compressed by another version)
            self.misses += 1
            return None
        header, mm, arrays = mapped
        try:
            value = opener(arrays, header["meta"])
        except (ValueError, KeyError, TypeError):
            self.misses += 1
            return None
        _release(mm)  # the check's pages: later reads fault in what they use
        self._touch(path)
        if count:
            self.hits += 1
        self._mapped.put(key, (value, mm), len(mm))
        with self._lock:
            self._used[key] = mm
        return value

    @classmethod
    def _map(cls, fh: Any) -> tuple[dict[str, Any], mmap.mmap, dict[str, np.ndarray]] | None:
        """(header, mapping, arrays) of the open cache file ``fh``, its CRC-32 checked by reading it
        (not through the mapping); None when its payload is not raw; ValueError (or KeyError,
        TypeError) when it is damaged, an error mapping it included."""
        size = os.fstat(fh.fileno()).st_size
        header, start = cls._header(fh.read(min(size, 1 << 20)), size)
        if header.get("codec") != "raw":
            return None
        fh.seek(start)
        crc, buf = 0, bytearray(min(_CRC_CHUNK, max(size - start, 1)))
        view = memoryview(buf)
        while (n := fh.readinto(view)) > 0:
            crc = zlib.crc32(view[:n], crc)
        if crc != header["crc32"]:
            raise ValueError("its payload does not match its checksum")
        try:
            mm = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_COPY)  # size > 0: the header is there
        except OSError as exc:
            raise ValueError(f"it cannot be mapped ({exc})") from None
        if any(not 0 <= int(at) <= int(at) + int(nb) <= size - start for *_, at, nb in header["layout"]):
            raise ValueError("an array of its layout lies outside its payload")
        return header, mm, unpack_arrays(np.frombuffer(mm, np.uint8), header["layout"], base=-start, copy=False)

    def release(self, sweep: bool = False) -> int:
        """Release the pages of the mapped values handed out since the last call
        (``MADV_DONTNEED``: they leave this process's resident memory and stay in the operating
        system's page cache, so a later read is a minor fault). A service calls it after each
        request: the page cache maps a file in folios of up to 2 MB, so a walk of a few rows in
        each of a graph's webs maps most of the graph, and without this the service would hold
        every graph it walked. ``sweep`` (a service, after each request): also drop the mappings
        whose file was removed from the folder (by any process's trim), so their disk blocks are
        freed once no caller holds them. The number of mappings released. O(mappings used), with
        ``sweep`` O(mappings kept) (one ``stat`` each: too much for every graph a search asks
        for — with the sweep there, ``bench.app_scale`` on the 381k store, 480 mappings, gave a
        warm median of 64 ms against 53 ms without it, in two runs)."""
        with self._lock:
            used, self._used = self._used, {}
        for mm in used.values():
            _release(mm)
        if sweep:
            for key in self._mapped.oldest_first():  # a file another process removed: its disk freed once unused
                if not self._path(key).exists():
                    self._mapped.discard(key)
        return len(used)

    def _scan(self) -> tuple[int, list[tuple[float, int, str]]]:
        """(bytes, [(mtime, size, path)]) of the cache files in the folder."""
        files = []
        try:
            subs = list(os.scandir(self.folder))
        except OSError:
            return 0, []
        for sub in subs:
            if not sub.is_dir(follow_symlinks=False):
                continue
            try:
                for e in os.scandir(sub.path):
                    if e.name.endswith(".mwc"):
                        st = e.stat(follow_symlinks=False)
                        files.append((st.st_mtime, st.st_size, e.path))
            except OSError:
                continue
        return sum(f[1] for f in files), files

    def trim(self, to: float = 0.8) -> int:
        """Remove the least recently used files until the folder holds at most ``to`` × the
        bound; the bytes removed. O(files) (one listing)."""
        with self._lock:
            total, files = self._scan()
            removed = 0
            for _, size, path in sorted(files):
                if total - removed <= to * self.max_bytes:
                    break
                try:
                    os.unlink(path)
                    removed += size
                except OSError:
                    continue
            self._bytes = total - removed
        return removed

    def stats(self) -> dict[str, Any]:
        mapped = self._mapped.stats()
        return {"folder": str(self.folder), "max_bytes": self.max_bytes, "hits": self.hits,
                "misses": self.misses, "writes": self.writes, "damaged": self.damaged,
                "mapped": {"entries": mapped["entries"], "bytes": mapped["bytes"], "hits": mapped["hits"]}}
