"""The content-keyed file cache (store/filecache.py; issue 25, part 5): round trips, damage read as
missing and removed, the bound kept by least recent use, a cache that never fails its caller."""

from __future__ import annotations

import os

import numpy as np
import pytest
from motionweb.store.filecache import FileCache, default_folder
from smaps import HAVE_SMAPS, mapping_rss_kb

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


def _damage(path, how: str, cut: int = 9) -> None:
    """Damage the cache file ``path``: a payload bit flipped, ``cut`` bytes cut off its end,
    garbage, nothing, its header broken, or an array said to lie past the file's end."""
    raw = bytearray(path.read_bytes())
    if how == "flip":
        raw[-5] ^= 0x40
    elif how == "truncate":
        raw = raw[:-cut]
    elif how == "garbage":
        raw = bytearray(b"\x00\xff" * 50)
    elif how == "empty":
        raw = bytearray()
    elif how == "header":
        raw[20:30] = b"}}}}}}}}}}"
    else:
        raw = bytearray(bytes(raw).replace(b'"<i8", [5000]', b'"<i8", [9000]'))
    path.write_bytes(bytes(raw))


@pytest.mark.parametrize("damage", ["flip", "truncate", "garbage", "empty", "header"])
def test_a_damaged_file_reads_as_missing_and_is_removed(tmp_path, damage) -> None:
    fc = FileCache(tmp_path, 1 << 20)
    fc.put(KEY, _arrays(np.random.default_rng(1)), {"x": 1})
    path = tmp_path / KEY[:2] / f"{KEY}.mwc"
    _damage(path, damage)
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


def _opened(arrays: dict[str, np.ndarray], meta: dict) -> tuple[dict[str, np.ndarray], dict]:
    return arrays, meta


def test_a_raw_value_reads_back_whole_and_mapped(tmp_path) -> None:
    """Issue 25 part 5: a value put ``raw`` (the walk graphs) reads back by :meth:`get` as arrays
    of its own and by :meth:`open_mapped` as aligned, writable views of the file, opened once per
    cache (kept in its LRU of mappings), counted a hit only when opened from disk."""
    fc = FileCache(tmp_path, 1 << 20)
    arrays = _arrays(np.random.default_rng(3))
    assert fc.put(KEY, arrays, {"n": 5}, raw=True)
    got, meta = fc.get(KEY)
    assert meta == {"n": 5} and all(np.array_equal(got[k], a) and got[k].flags.writeable for k, a in arrays.items())
    other = FileCache(tmp_path, 1 << 20)  # another process
    value = other.open_mapped(KEY, _opened)
    mapped, meta = value
    assert meta == {"n": 5} and set(mapped) == set(arrays) and (other.hits, other.misses) == (1, 0)
    for k, a in arrays.items():
        m = mapped[k]
        assert m.dtype == a.dtype and m.shape == a.shape and np.array_equal(m, a), k
        assert m.flags.writeable and m.flags.c_contiguous
        if a.size:
            assert m.ctypes.data % 64 == 0 and not m.flags.owndata, k
    assert other.open_mapped(KEY, _opened) is value and other.hits == 1  # kept: no second open
    assert other.stats()["mapped"] == {"entries": 1, "bytes": (tmp_path / KEY[:2] / f"{KEY}.mwc").stat().st_size,
                                       "hits": 1}
    assert other.release() == 1 and other.release() == 0  # only mappings used since the last release
    (tmp_path / KEY[:2] / f"{KEY}.mwc").unlink()  # removed from the folder: the mapping still reads
    assert np.array_equal(mapped["i8"], arrays["i8"])
    # a file this process just wrote is opened without counting a hit; a compressed one is not mapped
    assert fc.put(KEY, arrays, {}, raw=True) and fc.open_mapped(KEY, _opened, count=False) is not None
    assert fc.hits == 1  # the get above
    assert fc.put("cd" * 32, arrays, {}) and fc.open_mapped("cd" * 32, _opened) is None
    assert (tmp_path / "cd" / f"{'cd' * 32}.mwc").exists()


@pytest.mark.parametrize("damage", ["flip", "truncate", "header", "layout"])
def test_a_damaged_raw_file_is_not_mapped_and_is_removed(tmp_path, damage) -> None:
    fc = FileCache(tmp_path, 1 << 20)
    arrays = {"a": np.arange(5000, dtype=np.int64), "b": np.ones(3, np.float32)}
    fc.put(KEY, arrays, {}, raw=True)
    path = tmp_path / KEY[:2] / f"{KEY}.mwc"
    _damage(path, damage, cut=4096)
    assert fc.open_mapped(KEY, _opened) is None and fc.damaged == 1 and not path.exists()
    assert fc.put(KEY, arrays, {}, raw=True) and np.array_equal(fc.open_mapped(KEY, _opened)[0]["a"], arrays["a"])


def test_a_refused_mapping_stays_for_the_caller_to_replace(tmp_path) -> None:
    fc = FileCache(tmp_path, 1 << 20)
    fc.put(KEY, {"a": np.arange(10)}, {"layout": 1}, raw=True)

    def refuse(arrays, meta):
        raise ValueError("another layout")

    assert fc.open_mapped(KEY, refuse) is None and fc.misses == 1 and fc.damaged == 0
    assert (tmp_path / KEY[:2] / f"{KEY}.mwc").exists() and fc.stats()["mapped"]["entries"] == 0


def test_mappings_are_bounded_and_those_of_removed_files_dropped(tmp_path) -> None:
    """A process keeps at most half the cache's bound of files mapped (least recently used
    dropped), and :meth:`release` drops the mappings of files removed from the folder (by
    another process's trim): their disk is freed once unused."""
    big = {"x": np.random.default_rng(4).random(4000)}  # 32 kB
    fc = FileCache(tmp_path, 200_000)
    keys = [f"{i:064x}" for i in range(1, 5)]
    for k in keys:
        assert fc.put(k, big, {}, raw=True)
        assert fc.open_mapped(k, _opened, count=False) is not None
    st = fc.stats()["mapped"]
    assert st["bytes"] <= 100_000 and st["entries"] == 2
    (tmp_path / keys[-1][:2] / f"{keys[-1]}.mwc").unlink()
    fc.release()
    assert fc.stats()["mapped"]["entries"] == 2  # pages only
    fc.release(sweep=True)
    assert fc.stats()["mapped"]["entries"] == 1
    assert fc.open_mapped(keys[-1], _opened) is None and fc.open_mapped(keys[-2], _opened) is not None


def test_mappings_are_bounded_by_the_open_files_limit(tmp_path, monkeypatch) -> None:
    """Each mapping holds a file descriptor: a process keeps at most a quarter of its soft limit
    on open files mapped (at least 16), and the descriptors of the mappings it dropped are closed."""
    import gc
    import os
    import resource

    from motionweb.store import filecache

    monkeypatch.setattr(filecache.resource, "getrlimit", lambda what: (80, 4096))
    assert filecache.mapping_slots() == 20
    monkeypatch.setattr(filecache.resource, "getrlimit", lambda what: (8, 4096))
    assert filecache.mapping_slots() == 16
    monkeypatch.setattr(filecache.resource, "getrlimit", lambda what: (resource.RLIM_INFINITY,) * 2)
    assert filecache.mapping_slots() == 1 << 14
    monkeypatch.setattr(filecache.resource, "getrlimit", lambda what: (80, 4096))
    fc = FileCache(tmp_path, 1 << 30)
    fds = len(os.listdir("/proc/self/fd")) if os.path.isdir("/proc/self/fd") else None
    for i in range(1, 41):
        key = f"{i:064x}"
        assert fc.put(key, {"x": np.full(100, float(i))}, {}, raw=True)
        assert fc.open_mapped(key, _opened, count=False) is not None
    fc.release()
    gc.collect()
    assert fc.stats()["mapped"]["entries"] == 20
    if fds is not None:
        assert len(os.listdir("/proc/self/fd")) <= fds + 20


@pytest.mark.skipif(not HAVE_SMAPS, reason="needs Linux's /proc/self/smaps")
def test_release_drops_the_pages_a_walk_read(tmp_path) -> None:
    """After :meth:`release`, the mapped pages read leave the process's resident memory; the
    values still read the same (from the page cache)."""
    fc = FileCache(tmp_path, 1 << 30)
    a = np.random.default_rng(5).random(2_000_000)  # 16 MB
    fc.put(KEY, {"a": a}, {}, raw=True)
    path = tmp_path / KEY[:2] / f"{KEY}.mwc"
    mapped = fc.open_mapped(KEY, _opened)[0]["a"]
    assert mapping_rss_kb(path) < 4096  # the open's own check released
    assert float(mapped.sum()) == float(a.sum())
    assert mapping_rss_kb(path) > 8000
    assert fc.release() == 1 and mapping_rss_kb(path) == 0
    assert np.array_equal(mapped, a)
