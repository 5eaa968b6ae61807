"""The Zarr store (design §9): round trips, shards, complete-only objects."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import zarr
from fixtures import ragged_web
from motionweb.store.keys import feature_key, web_key
from motionweb.store.zarr_store import MotionStore

SHA_A = "a" * 64
SHA_B = "b" * 64


def write_shards(store: MotionStore, seed: int, shards: int, per_shard: int, sha: str) -> list[str]:
    """Write ``shards`` batches of ``per_shard`` random ragged webs (one shard each); their keys."""
    rng = np.random.default_rng(seed)
    keys = []
    for s in range(shards):
        batch = [(web_key(f"{s}{i:063d}", sha, "wd"), ragged_web(rng), {}) for i in range(per_shard)]
        store.write_webs(batch)
        keys += [k for k, _, _ in batch]
    return keys


@pytest.fixture(params=["local", "memory"])
def store(request, tmp_path) -> MotionStore:
    if request.param == "local":
        return MotionStore(str(tmp_path / "store"))
    return MotionStore(f"memory://motionweb-test-{tmp_path.name}/store")


def test_features_round_trip(store: MotionStore):
    rng = np.random.default_rng(0)
    feats = {10.0: rng.random((17, 75, 3), dtype=np.float32), 30.0: rng.random((5000, 75, 3), dtype=np.float32)}
    w = np.full(75, 1 / 75)
    key = store.write_features(SHA_A, "fd1", feats, w, {"path": "walk/a.bvh"})
    assert key == feature_key(SHA_A, "fd1")
    assert store.has_features(SHA_A, "fd1", [10.0, 30.0])
    assert not store.has_features(SHA_A, "fd1", [20.0])
    assert not store.has_features(SHA_A, "other", [10.0])
    got, gw = store.read_features(SHA_A, "fd1")
    assert set(got) == {10.0, 30.0}
    for r, f in feats.items():
        np.testing.assert_array_equal(got[r], f)
        assert got[r].dtype == np.float32
    np.testing.assert_array_equal(gw, w)
    with pytest.raises(KeyError):
        store.read_features(SHA_B, "fd1")


def test_web_round_trip_ragged(store: MotionStore):
    arrays = ragged_web(np.random.default_rng(1))
    key = web_key(SHA_A, SHA_B, "wd1")
    assert not store.has(key)
    store.write_web(key, arrays, {"n_chains": 3})
    assert store.has(key)
    got, attrs = store.read_web_arrays(key)
    assert set(got) == set(arrays) and attrs["n_chains"] == 3
    for k, v in arrays.items():
        np.testing.assert_array_equal(got[k], v)
        assert got[k].dtype == v.dtype and got[k].shape == v.shape
    # ragged access: path i is values[offsets[i]:offsets[i+1]]
    off = got["paths_offsets"]
    assert [off[i + 1] - off[i] for i in range(len(off) - 1)] == [5, 0, 12]


def test_incomplete_object_is_not_present(tmp_path):
    store = MotionStore(str(tmp_path / "s"))
    key = web_key(SHA_A, SHA_B, "wd1")
    store.write_web(key, ragged_web(np.random.default_rng(2)))
    (shard,) = [p.relative_to(tmp_path / "s") for p in (tmp_path / "s" / "webs" / "shards" / "wd1").iterdir() if p.is_dir()]
    g = zarr.open(store=store.zstore, path=str(shard), mode="r+")
    g.attrs["complete"] = False  # as if the writer died before marking it
    fresh = MotionStore(str(tmp_path / "s"))
    assert not fresh.has(key)
    with pytest.raises(KeyError):
        fresh.read_web_arrays(key)
    store.write_features(SHA_A, "fd1", {10.0: np.zeros((3, 2, 3), np.float32)}, np.ones(2))
    g = zarr.open(store=store.zstore, path=feature_key(SHA_A, "fd1"), mode="r+")
    g.attrs["complete"] = False
    assert not store.has_features(SHA_A, "fd1", [10.0])
    with pytest.raises(KeyError):
        store.read_features(SHA_A, "fd1")


def test_a_batch_of_webs_shares_one_shard(tmp_path):
    """compute_web_batch writes its webs together: one Zarr array, every web readable by key
    (also from another store instance, e.g. a reader), attributes kept per web."""
    store = MotionStore(str(tmp_path / "s"))
    rng = np.random.default_rng(6)
    keys = [web_key(SHA_A, SHA_B, "wd1"), web_key(SHA_A, SHA_A, "wd1"), web_key(SHA_B, SHA_B, "wd2")]
    webs = {k: ragged_web(rng) for k in keys}
    store.write_webs([(k, a, {"n": i}) for i, (k, a) in enumerate(webs.items())])
    assert sum(p.is_dir() for p in (tmp_path / "s" / "webs" / "shards" / "wd1").iterdir()) == 1  # per digest
    reader = MotionStore(str(tmp_path / "s"), read_only=True)
    assert reader.web_keys("wd1") == set(keys[:2]) and reader.web_keys("wd2") == {keys[2]}
    for i, (k, arrays) in enumerate(webs.items()):
        got, attrs = reader.read_web_arrays(k)
        assert attrs == {"n": i} and reader.web_attrs(k) == {"n": i}
        for name, v in arrays.items():
            np.testing.assert_array_equal(got[name], v)
            assert got[name].dtype == v.dtype and got[name].shape == v.shape
    assert not reader.has(web_key(SHA_B, SHA_A, "wd1")) and reader.web_attrs(web_key(SHA_B, SHA_A, "wd1")) == {}
    # a shard is opened once per store instance, not once per web read (its index can be large)
    opened = []
    fresh = MotionStore(str(tmp_path / "s"), read_only=True)
    original = fresh._take_in_shard
    fresh._take_in_shard = lambda key: opened.append(key) or original(key)
    for _ in range(3):
        for k in keys:
            fresh.read_web_arrays(k)
    assert sorted(opened) == sorted(set(opened)) and len(opened) == 2  # wd1's and wd2's shard


def test_a_shard_of_many_chunks_is_one_object(tmp_path):
    """A batch's webs are one Zarr v3 shard: its chunks (SHARD_CHUNK bytes each) are one stored
    object beside the array's zarr.json, however many there are, and every web reads back."""
    from motionweb.store.zarr_store import SHARD_CHUNK

    store = MotionStore(str(tmp_path / "s"))
    rng = np.random.default_rng(9)
    big = {"paths_cells": rng.integers(0, 1000, (3 * SHARD_CHUNK // 8, 2)).astype(np.int32),
           "paths_offsets": np.array([0, 3 * SHARD_CHUNK // 8], np.int64)}
    keys = [web_key(SHA_A, SHA_B, "wd"), web_key(SHA_B, SHA_A, "wd")]
    store.write_webs([(keys[0], big, {}), (keys[1], ragged_web(rng), {})])
    (shard,) = [p for p in (tmp_path / "s" / "webs" / "shards" / "wd").iterdir() if p.is_dir()]
    files = [p for p in shard.rglob("*") if p.is_file()]
    assert sorted(p.name for p in files) == ["0", "zarr.json"], files  # > 3 chunks of bytes, one object
    got, _ = MotionStore(str(tmp_path / "s"), read_only=True).read_web_arrays(keys[0])
    np.testing.assert_array_equal(got["paths_cells"], big["paths_cells"])


def test_a_reader_keeps_each_shard_index_compact(tmp_path):
    """A read-only store (the app's search workers) takes in each shard once: its array opened
    without its attributes and its entries as compact text, no parsed entry kept; every web reads
    back as the writer wrote it, from the newest shard holding it, and a shard written after the
    reader opened is found."""
    store = MotionStore(str(tmp_path / "s"))
    rng = np.random.default_rng(3)
    shas = [f"{i:02x}" * 32 for i in range(12)]
    written = {}
    for i in range(len(shas) - 1):  # one shard per batch
        batch = [(web_key(shas[i], shas[j], "wd"), ragged_web(rng)) for j in (i, i + 1)]
        store.write_webs([(k, w, {"i": i}) for k, w in batch])
        written.update(batch)
    again = web_key(shas[0], shas[0], "wd")  # written again in a later shard: the newer one serves
    written[again] = ragged_web(rng)
    store.write_webs([(again, written[again], {"i": "again"})])
    reader = MotionStore(str(tmp_path / "s"), read_only=True)
    for k in [*written, *reversed(written)]:
        got, _ = reader.read_web_arrays(k)
        for name, arr in written[k].items():
            np.testing.assert_array_equal(got[name], arr)
        assert reader.verify(k) is None
    assert reader.web_attrs(again) == {"i": "again"}
    assert reader.web_keys("wd") == set(written)
    assert len(reader._reader_shards) == len(shas)
    assert not reader._webs and not reader._shards  # no parsed entry, no array with its attributes
    assert all(not dict(rs.array.attrs) for rs in reader._reader_shards)
    late = web_key(shas[-1], shas[-1], "wd")
    store.write_webs([(late, ragged_web(rng), {})])
    assert reader.has(late) and not reader.has(web_key(shas[-1], shas[0], "wd"))


def test_a_reader_reads_local_shards_directly_as_zarr_does(tmp_path):
    """A reader's direct read of a local shard (chunks located by the shard's index, decompressed
    with Blosc) gives zarr's bytes for every web, over chunk boundaries; damaged bytes are told
    by zarr's path, naming the web."""
    from motionweb.store.zarr_store import SHARD_CHUNK, StoreIntegrityError

    store = MotionStore(str(tmp_path / "s"))
    rng = np.random.default_rng(4)
    big = {"paths_cells": rng.integers(0, 1000, (SHARD_CHUNK // 6, 2)).astype(np.int32)}  # spans chunks
    keys = [web_key(f"{i:02x}" * 32, "ff" * 32, "wd") for i in range(6)]
    webs = [big if i == 2 else ragged_web(rng) for i in range(6)]
    store.write_webs([(k, w, {}) for k, w in zip(keys, webs, strict=True)])
    reader = MotionStore(str(tmp_path / "s"), read_only=True)
    for k, w in zip(keys, webs, strict=True):
        shard, e = reader._web_entry(k)
        direct = reader._read_local(shard, e["start"], e["nbytes"])
        assert direct is not None
        np.testing.assert_array_equal(direct, np.asarray(reader._shard(shard)[e["start"]:e["start"] + e["nbytes"]]))
        got, _ = reader.read_web_arrays(k)
        for name, arr in w.items():
            np.testing.assert_array_equal(got[name], arr)
    assert len(reader._local_layouts) == 1
    (chunk,) = [p for p in (tmp_path / "s" / "webs" / "shards" / "wd").rglob("c/0")]
    data = bytearray(chunk.read_bytes())
    data[40:60] = bytes(20)  # inside the first compressed chunk
    chunk.write_bytes(bytes(data))
    damaged = MotionStore(str(tmp_path / "s"), read_only=True)
    with pytest.raises(StoreIntegrityError, match=keys[0]):
        damaged.read_web_arrays(keys[0])


def _damage_a_shard(root, keys):
    """Zero 20 bytes of the first shard file of ``root``'s webs: (a reader opened after it, the
    keys of ``keys`` its one-pass read no longer gives)."""
    chunk = min((root / "webs" / "shards" / "wd").rglob("c/0"))
    data = bytearray(chunk.read_bytes())
    data[40:60] = bytes(20)
    chunk.write_bytes(bytes(data))
    damaged = MotionStore(str(root), read_only=True)
    return damaged, [k for k, a in damaged.iter_web_arrays(keys) if a is None]


def test_a_pass_over_many_webs_reads_each_chunk_once_and_gives_each_web(tmp_path, monkeypatch):
    """``iter_web_arrays`` gives every asked web once, equal to a read alone, over shards and
    chunk boundaries, in the store's order, each inner chunk decompressed once; a web whose bytes
    differ from their checksum, or that no shard holds, comes back as None (read alone, it names
    the damage); a writer (not a reader) gives None for every web."""
    from motionweb.store import zarr_store
    from motionweb.store.zarr_store import SHARD_CHUNK, StoreIntegrityError

    store = MotionStore(str(tmp_path / "s"))
    rng = np.random.default_rng(5)
    big = {"paths_cells": rng.integers(0, 1000, (SHARD_CHUNK // 5, 2)).astype(np.int32)}  # spans chunks
    written = {}
    for s in range(3):  # three shards
        batch = [(web_key(f"{s}{i:x}" * 32, "ee" * 32, "wd"), big if i == 4 else ragged_web(rng)) for i in range(9)]
        store.write_webs([(k, w, {}) for k, w in batch])
        written.update(batch)
    ask = list(written)[::-1][:20] + [web_key("dd" * 32, "dd" * 32, "wd")]  # and one never written
    reader = MotionStore(str(tmp_path / "s"), read_only=True)
    decodes = []
    real = zarr_store._BLOSC.decode
    monkeypatch.setattr(zarr_store, "_BLOSC", type("B", (), {"decode": lambda self, c, out: decodes.append(1) or real(c, out=out)})())
    got = list(reader.iter_web_arrays(ask))
    assert sorted(k for k, _ in got) == sorted(ask)
    assert dict(got)[ask[-1]] is None
    for k, arrays in got:
        if k == ask[-1]:
            continue
        for name, arr in written[k].items():
            np.testing.assert_array_equal(arrays[name], arr)
    assert sum(a is not None for _, a in got) == 20
    chunks = sum(len(lay[2]) for lay in reader._local_layouts.values())  # the chunks of the 3 shards
    assert len(decodes) <= chunks, (len(decodes), chunks)
    order = [(reader._web_entry(k)[0], reader._web_entry(k)[1]["start"]) for k, a in got if a is not None]
    runs = [sh for i, (sh, _) in enumerate(order) if i == 0 or order[i - 1][0] != sh]
    assert len(runs) == len(set(runs)) == 3  # shard by shard
    assert all(a[1] < b[1] for a, b in itertools.pairwise(order) if a[0] == b[0])  # by offset in each
    monkeypatch.undo()
    damaged, bad = _damage_a_shard(tmp_path / "s", list(written))
    assert bad
    with pytest.raises(StoreIntegrityError, match=bad[0]):
        damaged.read_web_arrays(bad[0])
    writer = MotionStore(str(tmp_path / "s"))  # a writer (the index verifying what it reuses) reads so too
    assert [k for k, a in writer.iter_web_arrays(list(written)) if a is None] == bad


@pytest.mark.parametrize("threads", [1, 2])
def test_map_web_arrays_answers_as_the_one_thread_pass(tmp_path, threads):
    """``map_web_arrays``: ``fn`` of each web equal to :meth:`iter_web_arrays`'s arrays, the shards
    shared among threads (``fn`` called in the pool's threads with 2), the webs that pass does not
    give (never written, damaged) listed for the caller, none answered."""
    import threading

    store = MotionStore(str(tmp_path / "s"))
    rng = np.random.default_rng(11)
    written = {}
    for s in range(3):
        batch = [(web_key(f"{s}{i:x}" * 32, "ab" * 32, "wd"), ragged_web(rng)) for i in range(7)]
        store.write_webs([(k, w, {}) for k, w in batch])
        written.update(batch)
    never = web_key("dd" * 32, "dd" * 32, "wd")
    reader = MotionStore(str(tmp_path / "s"), read_only=True)
    where = []

    def fn(arrays):
        where.append(threading.current_thread() is threading.main_thread())
        return {name: a.sum() for name, a in arrays.items()}, sorted(arrays)

    got, alone = reader.map_web_arrays([*written, never], fn, threads=threads)
    assert alone == [never] and set(got) == set(written)
    for key, arrays in reader.iter_web_arrays(list(written)):
        assert got[key] == ({name: a.sum() for name, a in arrays.items()}, sorted(arrays))
    assert all(where) if threads == 1 else not any(where)
    damaged, bad = _damage_a_shard(tmp_path / "s", list(written))
    got, alone = damaged.map_web_arrays(list(written), fn, threads=threads)
    assert bad and sorted(alone) == sorted(bad) and set(got) == set(written) - set(bad)


def test_damaged_or_missing_chunks_raise_naming_the_object(tmp_path):
    from motionweb.store.zarr_store import StoreIntegrityError

    store = MotionStore(str(tmp_path / "s"))
    rng = np.random.default_rng(8)
    fk = store.write_features(SHA_A, "fd", {30.0: rng.random((50, 4, 3)).astype(np.float32)}, np.ones(4))
    wk = web_key(SHA_A, SHA_B, "wd")
    store.write_web(wk, ragged_web(rng))
    assert store.verify(fk) is None and store.verify(wk) is None
    (feature_chunk,) = [p for p in (tmp_path / "s" / "features").rglob("c/*") if p.is_file()]
    feature_chunk.unlink()  # zarr reads a missing chunk as zeros: the checksum tells
    with pytest.raises(StoreIntegrityError, match=fk):
        MotionStore(str(tmp_path / "s")).read_features(SHA_A, "fd")
    (web_chunk,) = [p for p in (tmp_path / "s" / "webs").rglob("c/*") if p.is_file()]
    web_chunk.write_bytes(web_chunk.read_bytes()[:10])  # truncated: blosc cannot decode it
    fresh = MotionStore(str(tmp_path / "s"))
    with pytest.raises(StoreIntegrityError, match="unreadable"):
        fresh.read_web_arrays(wk)
    assert fresh.verify(wk).startswith("is unreadable") and fresh.verify(fk).startswith("is damaged")
    assert fresh.verify(web_key(SHA_B, SHA_B, "wd")) == "missing"


def test_a_reader_given_the_recorded_shard_takes_in_that_shard_alone(tmp_path):
    """write_webs says where each web went; a reader given it (a generation's record) takes in
    that shard only, not every shard of the digest; a hint that is wrong, gone, damaged or not a
    shard of the key's digest is ignored (the reader lists the shards, as without one)."""
    store = MotionStore(str(tmp_path / "s"))
    rng = np.random.default_rng(11)
    written, where = {}, {}
    for s in range(4):
        batch = {web_key(f"{s}{i:063d}", SHA_B, "wd"): ragged_web(rng) for i in range(5)}
        shards = store.write_webs([(k, w, {}) for k, w in batch.items()])
        assert set(shards) == set(batch) and len(set(shards.values())) == 1
        assert all(sh.startswith("webs/shards/wd/") for sh in shards.values())
        written |= batch
        where |= shards
    assert len(set(where.values())) == 4
    key = sorted(written)[7]
    reader = MotionStore(str(tmp_path / "s"), read_only=True)
    got, _ = reader.read_web_arrays(key, where[key])
    np.testing.assert_array_equal(got["paths_cells"], written[key]["paths_cells"])
    assert list(reader._seen_shards) == [where[key]]  # one shard taken in
    same = [k for k in written if where[k] == where[key]]
    assert {k for k, a in reader.iter_web_arrays(same, where) if a is not None} == set(same)
    assert list(reader._seen_shards) == [where[key]]
    other = max(written)
    for hint in (where[key], "webs/shards/wd/none", "webs/shards/other/" + where[other].rsplit("/", 1)[1],
                 "webs/shards/wd/../wd/" + where[other].rsplit("/", 1)[1], "/etc", ""):
        fresh = MotionStore(str(tmp_path / "s"), read_only=True)
        got, _ = fresh.read_web_arrays(other, hint)  # a wrong hint: found by listing the shards
        np.testing.assert_array_equal(got["paths_cells"], written[other]["paths_cells"])
        assert len(fresh._seen_shards) == 4
    damaged = tmp_path / "s" / where[other] / "zarr.json"
    damaged.write_text("{not json")
    fresh = MotionStore(str(tmp_path / "s"), read_only=True)
    with pytest.raises(KeyError, match=other):
        fresh.read_web_arrays(other, where[other])
    assert where[other] in fresh._bad_hints and len(fresh._seen_shards) == 3


@pytest.mark.parametrize("threads", [1, 3])
def test_verify_webs_in_one_pass_says_what_verify_says_of_each(tmp_path, threads):
    """verify_webs (one pass per shard in the store's order, the shards shared among threads) gives
    each web the answer verify gives it, in the order asked: sound, missing, damaged bytes, a
    checksum that differs from the manifest's."""
    store = MotionStore(str(tmp_path / "s"))
    keys = write_shards(store, 12, 3, 6, SHA_B)
    chunk = sorted((tmp_path / "s" / "webs" / "shards" / "wd").rglob("c/0"))[1]
    data = bytearray(chunk.read_bytes())
    data[40:60] = bytes(20)
    chunk.write_bytes(bytes(data))
    store = MotionStore(str(tmp_path / "s"))
    ask = [*keys, web_key("f" * 64, SHA_B, "wd")]
    expected = {keys[0]: "0" * 64, keys[1]: store.recorded_checksum(keys[1])}
    got = store.verify_webs(ask, expected, threads=threads)
    want = {k: MotionStore(str(tmp_path / "s")).verify(k, expected.get(k)) for k in ask}
    assert got == want and list(got) == ask
    assert got[keys[1]] is None and got[keys[0]] == "checksum differs from the manifest's" and got[ask[-1]] == "missing"
    assert 0 < sum(v is not None and v != "missing" and k != keys[0] for k, v in got.items()) < len(keys)


@pytest.mark.parametrize("pass_bytes", [1, 5000, 1 << 25])
def test_a_pass_in_runs_of_any_size_answers_as_reads_alone(tmp_path, monkeypatch, pass_bytes):
    """``_shard_pass`` takes a shard's webs in runs of at most ``PASS_BYTES`` decompressed bytes
    (a larger web alone): whatever the run size, verify_webs and map_web_arrays answer as each
    web read alone does, a damaged chunk costing only the webs of its run (read alone, they say
    why)."""
    from motionweb.store import zarr_store

    monkeypatch.setattr(zarr_store, "PASS_BYTES", pass_bytes)
    store = MotionStore(str(tmp_path / "s"))
    keys = write_shards(store, 31, 2, 14, SHA_A)
    alone = {k: store.read_web_arrays(k)[0] for k in keys}
    got, missed = MotionStore(str(tmp_path / "s")).map_web_arrays(keys, lambda a: {n: v.copy() for n, v in a.items()})
    assert missed == [] and sorted(got) == sorted(keys)
    for k in keys:
        assert alone[k].keys() == got[k].keys()
        for name in alone[k]:
            np.testing.assert_array_equal(got[k][name], alone[k][name])
    assert MotionStore(str(tmp_path / "s")).verify_webs(keys) == dict.fromkeys(keys)
    chunk = sorted((tmp_path / "s" / "webs" / "shards" / "wd").rglob("c/0"))[0]
    data = bytearray(chunk.read_bytes())
    data[60:80] = bytes(20)  # inside the first inner chunk of the first shard
    chunk.write_bytes(bytes(data))
    fresh = MotionStore(str(tmp_path / "s"))
    want = {k: MotionStore(str(tmp_path / "s")).verify(k) for k in keys}
    assert fresh.verify_webs(keys) == want
    assert any(v is not None for v in want.values()) and want[keys[-1]] is None


def test_features_are_read_from_their_chunk_files_as_zarr_reads_them(tmp_path, monkeypatch):
    """A packed object on a local disk is read from its chunk files without zarr (the edge chunk
    padded, a missing chunk the fill value) and gives zarr's bytes; damage is found and named as
    through zarr; the header an instance keeps is dropped when it rewrites the object."""
    from motionweb.store import zarr_store
    from motionweb.store.zarr_store import StoreIntegrityError

    monkeypatch.setattr(zarr_store, "PACKED_CHUNK", 4096)  # several chunks, the last one short
    rng = np.random.default_rng(4)
    feats = {30.0: rng.random((40, 30, 3)).astype(np.float32)}
    store = MotionStore(str(tmp_path / "s"))
    key = store.write_features(SHA_A, "fd", feats, np.ones(30))
    fresh = MotionStore(str(tmp_path / "s"))
    got, _ = fresh.read_features(SHA_A, "fd")
    np.testing.assert_array_equal(got[30.0], feats[30.0])
    assert key in fresh._plain and fresh.verify(key) is None
    z = zarr.open_array(str(tmp_path / "s" / key), mode="r")
    n = z.shape[0]
    assert n % 4096 and n > 3 * 4096
    np.testing.assert_array_equal(fresh._read_plain(key, n, None), np.asarray(z[:]))
    again = {30.0: feats[30.0] + 1}
    fresh.write_features(SHA_A, "fd", again, np.ones(30))  # rewritten by this instance: read afresh
    np.testing.assert_array_equal(fresh.read_features(SHA_A, "fd")[0][30.0], again[30.0])
    chunks = sorted(p for p in (tmp_path / "s" / key / "c").iterdir())
    chunks[1].unlink()  # zarr reads a missing chunk as zeros: the checksum tells
    fresh = MotionStore(str(tmp_path / "s"))
    assert fresh.verify(key).startswith("is damaged")
    with pytest.raises(StoreIntegrityError, match=key):
        fresh.read_features(SHA_A, "fd")
    chunks[2].write_bytes(b"not blosc")
    assert MotionStore(str(tmp_path / "s")).verify(key).startswith("is unreadable")
