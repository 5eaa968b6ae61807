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
as ``store.zarr_store`` packs a web, the caller's metadata, the payload's size and CRC-32), then
the arrays' bytes compressed with Blosc (LZ4, byte shuffle).
"""

from __future__ import annotations

import json
import logging
import os
import threading
import uuid
import zlib
from pathlib import Path
from typing import Any

import numpy as np
from motionweb.store.zarr_store import pack_arrays, unpack_arrays
from numcodecs import Blosc

__all__ = ["FileCache", "default_folder"]

log = logging.getLogger(__name__)

MAGIC = b"MWFC1\n"
#: Blosc compresses one buffer of at most 2 GB; a larger value is not kept
MAX_VALUE_BYTES = 2**31 - 2**20
_CODEC = Blosc(cname="lz4", clevel=5, shuffle=Blosc.SHUFFLE)


#: environment variable naming the folder of motionweb's file caches (default: the user's cache folder)
CACHE_ENV = "MOTIONWEB_CACHE_DIR"


def default_folder(kind: str = "graphs") -> Path:
    """``$MOTIONWEB_CACHE_DIR/<kind>``, else ``$XDG_CACHE_HOME/motionweb/<kind>`` (``~/.cache`` without it)."""
    if os.environ.get(CACHE_ENV):
        return Path(os.environ[CACHE_ENV]) / kind
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "motionweb" / kind


def _is_key(key: str) -> bool:
    return 8 <= len(key) <= 128 and all(c in "0123456789abcdef" for c in key)


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

    def _path(self, key: str) -> Path:
        if not _is_key(key):
            raise ValueError(f"a file cache key is a lowercase hex digest, got {key!r}")
        return self.folder / key[:2] / f"{key}.mwc"

    def get(self, key: str) -> tuple[dict[str, np.ndarray], dict[str, Any]] | None:
        """The arrays and metadata kept under ``key``, or None (missing, damaged or unreadable;
        a damaged file is removed)."""
        path = self._path(key)
        try:
            raw = path.read_bytes()
        except OSError:
            self.misses += 1
            return None
        try:
            value = self._decode(raw)
        except (ValueError, KeyError, TypeError, RuntimeError) as exc:
            self.damaged += 1
            self.misses += 1
            log.warning("%s: damaged cache file removed (%s)", path, exc)
            path.unlink(missing_ok=True)
            return None
        try:
            os.utime(path)  # recently used: evicted last
        except OSError:
            pass
        self.hits += 1
        return value

    @staticmethod
    def _decode(raw: bytes) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        if not raw.startswith(MAGIC) or len(raw) < len(MAGIC) + 8:
            raise ValueError("not a cache file")
        n = int.from_bytes(raw[len(MAGIC):len(MAGIC) + 8], "little")
        start = len(MAGIC) + 8 + n
        header = json.loads(raw[len(MAGIC) + 8:start])
        payload = memoryview(raw)[start:]
        if len(payload) != header["compressed"] or zlib.crc32(payload) != header["crc32"]:
            raise ValueError("its payload does not match its checksum")
        buf = np.empty(header["nbytes"], np.uint8)
        if header["nbytes"]:
            _CODEC.decode(payload, out=buf)
        return unpack_arrays(buf, header["layout"], copy=False), header["meta"]

    def put(self, key: str, arrays: dict[str, np.ndarray], meta: dict[str, Any]) -> bool:
        """Keep ``arrays`` (flat numeric arrays) and ``meta`` (JSON) under ``key``; False when it
        was not kept (too large, or the folder cannot be written: a cache never fails its
        caller)."""
        path = self._path(key)
        parts, layout, nbytes = pack_arrays(arrays)
        if nbytes > MAX_VALUE_BYTES:
            return False
        payload = _CODEC.encode(np.concatenate(parts)) if nbytes else b""
        header = json.dumps({"layout": layout, "meta": meta, "nbytes": nbytes, "compressed": len(payload),
                             "crc32": zlib.crc32(payload)}).encode()
        tmp = path.with_name(f"{path.name}.tmp-{uuid.uuid4().hex[:8]}")
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            with open(tmp, "wb") as fh:
                fh.write(MAGIC + len(header).to_bytes(8, "little") + header)
                fh.write(payload)
            os.replace(tmp, path)
        except OSError as exc:
            log.debug("%s: not kept (%s)", path, exc)
            try:
                tmp.unlink(missing_ok=True)
            except OSError:
                pass
            return False
        self.writes += 1
        size = len(MAGIC) + 8 + len(header) + len(payload)
        with self._lock:
            self._bytes = (self._scan()[0] if self._bytes is None else self._bytes + size)
            over = self._bytes > self.max_bytes
        if over:
            self.trim()
        return True

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
        return {"folder": str(self.folder), "max_bytes": self.max_bytes, "hits": self.hits,
                "misses": self.misses, "writes": self.writes, "damaged": self.damaged}
