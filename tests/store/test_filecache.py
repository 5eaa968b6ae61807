"""The content-keyed file cache (store/filecache.py; issue 25, part 5): round trips, damage read as
missing and removed, the bound kept by least recent use, a cache that never fails its caller."""

from __future__ import annotations

import os

import numpy as np
import pytest
from motionweb.store.filecache import FileCache, default_folder

KEY = "ab" * 32


def _arrays(rng: np.random.Generator, n: int = 50) -> dict[str, np.ndarray]:
    return {"i4": rng.integers(-9, 9, n).astype(np.int32), "f4": rng.random(n).astype(np.float32),
            "i8": rng.integers(0, 2**40, (n, 3)), "empty": np.zeros(0, np.int32), "u1": np.arange(7, dtype=np.uint8)}


def test_round_trip_dtypes_shapes_meta(tmp_path) -> None:
    fc = FileCache(tmp_path / "c", 1 << 20)
    assert fc.get(KEY) is None and fc.misses == 1
    arrays = _arrays(np.random.default_rng(0))
    assert fc.put(KEY, arrays, {"rate": 30.0, "names": ["a", "b"]})
    got, meta = fc.get(KEY)
    assert meta == {"rate": 30.0, "names": ["a", "b"]} and set(got) == set(arrays)
    for k, a in arrays.items():
        assert got[k].dtype == a.dtype and got[k].shape == a.shape and np.array_equal(got[k], a)
        assert got[k].flags.c_contiguous and got[k].flags.writeable
    assert fc.put(KEY, {}, {}) and fc.get(KEY) == ({}, {})  # replaced; nothing at all kept too
    assert (fc.hits, fc.writes) == (2, 2)


@pytest.mark.parametrize("damage", ["flip", "truncate", "garbage", "empty", "header"])
def test_a_damaged_file_reads_as_missing_and_is_removed(tmp_path, damage) -> None:
    fc = FileCache(tmp_path, 1 << 20)
    fc.put(KEY, _arrays(np.random.default_rng(1)), {"x": 1})
    path = tmp_path / KEY[:2] / f"{KEY}.mwc"
    raw = bytearray(path.read_bytes())
    if damage == "flip":
        raw[-5] ^= 0x40
    elif damage == "truncate":
        raw = raw[:-9]
    elif damage == "garbage":
        raw = bytearray(b"\x00\xff" * 50)
    elif damage == "empty":
        raw = bytearray()
    else:
        raw[20:30] = b"}}}}}}}}}}"
    path.write_bytes(bytes(raw))
    assert fc.get(KEY) is None and fc.damaged == 1 and not path.exists()
    assert fc.put(KEY, {"a": np.arange(3)}, {}) and np.array_equal(fc.get(KEY)[0]["a"], np.arange(3))


def test_the_bound_drops_the_least_recently_used(tmp_path) -> None:
    rng = np.random.default_rng(2)
    big = {"x": rng.random(4000)}  # ~32 kB, random: it does not compress
    fc = FileCache(tmp_path, 100_000)
    keys = [f"{i:064x}" for i in range(1, 4)]
    for t, k in enumerate(keys):
        fc.put(k, big, {})
        os.utime(tmp_path / k[:2] / f"{k}.mwc", (1000 + t, 1000 + t))  # put in this order
    fc.get(keys[0])  # read now: the most recent
    fc.put(f"{9:064x}", big, {})  # over the bound: down to 80% of it, oldest first
    left = {k for k in [*keys, f"{9:064x}"] if (tmp_path / k[:2] / f"{k}.mwc").exists()}
    assert left == {keys[0], f"{9:064x}"}
    assert sum(p.stat().st_size for p in tmp_path.rglob("*.mwc")) <= 100_000


def test_keys_and_bounds_are_checked_and_a_broken_folder_never_fails_the_caller(tmp_path) -> None:
    with pytest.raises(ValueError, match="positive bound"):
        FileCache(tmp_path, 0)
    fc = FileCache(tmp_path / "file", 1 << 20)
    (tmp_path / "file").write_text("not a folder")
    for bad in ("../etc/passwd", "ABCDEF0123456789", "ab", "ab/cd" * 4):
        with pytest.raises(ValueError, match="hex digest"):
            fc.get(bad)
    assert fc.put(KEY, {"a": np.arange(3)}, {}) is False and fc.get(KEY) is None
    assert not list(tmp_path.glob("**/*.tmp-*"))


def test_default_folder_follows_the_environment(monkeypatch, tmp_path) -> None:
    monkeypatch.setenv("MOTIONWEB_CACHE_DIR", str(tmp_path))
    assert default_folder() == tmp_path / "graphs"
    monkeypatch.delenv("MOTIONWEB_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert default_folder("x") == tmp_path / "xdg" / "motionweb" / "x"
