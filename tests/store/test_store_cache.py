"""The Zarr store (design §9): round trips, content addressing, generation pointer semantics."""

from __future__ import annotations

import json

import numpy as np
import pytest
import zarr
from motionweb.flows.config import Config
from motionweb.store.cache import (
    Generation,
    MotionStore,
    feature_digest,
    feature_key,
    new_generation_id,
    now_iso,
    web_digest,
    web_key,
)

SHA_A = "a" * 64
SHA_B = "b" * 64


def ragged_web(rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Flat arrays of a web with three paths of different lengths (values + offsets)."""
    lengths = [5, 0, 12]
    offsets = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
    n = int(offsets[-1])
    return {
        "paths_cells": rng.integers(0, 100, size=(n, 2)).astype(np.int32),
        "paths_values": rng.random(n).astype(np.float32),
        "paths_offsets": offsets,
        "bridges": np.zeros((0, 4), np.int32),
        "shape": np.array([100, 80], np.int64),
        "rate": np.array([30.0]),
    }


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
    original = fresh._open
    fresh._open = lambda key: opened.append(key) or original(key)
    for _ in range(3):
        for k in keys:
            fresh.read_web_arrays(k)
    assert sorted(opened) == sorted(set(opened)) and len(opened) == 2  # wd1's and wd2's shard


def test_parameter_digests():
    base = Config()
    mw = Config.model_validate({"matchweb": {"valid_a": 0.3}})
    assert web_digest(mw) != web_digest(base)
    assert feature_digest(mw) == feature_digest(base)  # features are reused across web parameters
    feat = Config.model_validate({"features": {"window": 7}})
    assert feature_digest(feat) != feature_digest(base) and web_digest(feat) != web_digest(base)
    rates = Config.model_validate({"features": {"rates": [10.0, 20.0, 60.0]}})
    assert feature_digest(rates) == feature_digest(base)  # rates are part of the feature key itself
    assert web_digest(rates) != web_digest(base)
    grids = Config.model_validate({"matchweb": {"keep_grids": True}})
    assert web_digest(grids) == web_digest(base)


def _gen(store: MotionStore, webs: list[str]) -> Generation:
    return Generation(id=new_generation_id(), created=now_iso(),
                      webs=[{"a": f"x{i}", "b": f"y{i}", "key": k} for i, k in enumerate(webs)])


def test_generation_pointer_and_crash(tmp_path):
    store = MotionStore(str(tmp_path / "s"))
    assert store.current_id() is None and store.generation() is None
    k1 = web_key(SHA_A, SHA_A, "wd1")
    store.write_web(k1, ragged_web(np.random.default_rng(3)))
    g1 = _gen(store, [k1])
    store.commit(g1)
    assert store.current_id() == g1.id

    # a second run writes a new object then "crashes" before committing
    k2 = web_key(SHA_A, SHA_B, "wd1")

    def crashing_run():
        store.write_web(k2, ragged_web(np.random.default_rng(4)))
        raise RuntimeError("worker lost")

    with pytest.raises(RuntimeError):
        crashing_run()
    reader = MotionStore(str(tmp_path / "s"), read_only=True)
    assert reader.current_id() == g1.id
    assert [w["key"] for w in reader.generation().webs] == [k1]
    reader.read_web_arrays(k1)  # still readable
    # the next run resumes: the complete object from the crashed run is reused as cached
    assert store.has(k2)
    g2 = _gen(store, [k1, k2])
    g2.parent = g1.id
    store.commit(g2)
    assert store.current_id() == g2.id and store.generation_ids() == sorted([g1.id, g2.id])
    assert store.generation(g1.id).webs == g1.webs  # old generations stay readable
    with pytest.raises(PermissionError):
        reader.commit(_gen(reader, []))


def test_commit_refuses_missing_objects(tmp_path):
    store = MotionStore(str(tmp_path / "s"))
    with pytest.raises(RuntimeError, match="missing"):
        store.commit(_gen(store, [web_key(SHA_A, SHA_B, "nope")]))
    assert store.current_id() is None


def test_pointer_is_atomic_json(tmp_path):
    store = MotionStore(str(tmp_path / "s"))
    g = _gen(store, [])
    store.commit(g)
    data = json.loads((tmp_path / "s" / "current").read_text())
    assert data["generation"] == g.id
    assert not list((tmp_path / "s").glob("current.tmp-*"))


def test_gc_keeps_listed_objects(tmp_path):
    store = MotionStore(str(tmp_path / "s"))
    rng = np.random.default_rng(5)
    k_old = web_key(SHA_A, SHA_B, "wd0")
    k_new = web_key(SHA_A, SHA_B, "wd1")
    store.write_web(k_old, ragged_web(rng))
    store.commit(_gen(store, [k_old]))
    store.write_web(k_new, ragged_web(rng))
    store.commit(_gen(store, [k_new]))
    assert store.gc(keep=1) == [k_old]
    assert store.has(k_new) and not store.has(k_old)
    assert len(store.generation_ids()) == 1
