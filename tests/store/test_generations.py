"""Generations (design §9): pointer semantics, crashes, commit checks, gc."""

from __future__ import annotations

import json

import numpy as np
import pytest
from fixtures import ragged_web
from motionweb.store.generations import Generation, commit, current_id, gc, generation_ids, load_generation
from motionweb.store.keys import web_key
from motionweb.store.zarr_store import MotionStore, new_id, now_iso

SHA_A = "a" * 64
SHA_B = "b" * 64


def _gen(store: MotionStore, webs: list[str]) -> Generation:
    return Generation(id=new_id(), created=now_iso(),
                      webs=[{"a": f"x{i}", "b": f"y{i}", "key": k} for i, k in enumerate(webs)])


def test_generation_pointer_and_crash(tmp_path):
    store = MotionStore(str(tmp_path / "s"))
    assert current_id(store) is None and load_generation(store) is None
    k1 = web_key(SHA_A, SHA_A, "wd1")
    store.write_web(k1, ragged_web(np.random.default_rng(3)))
    g1 = _gen(store, [k1])
    commit(store, g1)
    assert current_id(store) == g1.id

    # a second run writes a new object then "crashes" before committing
    k2 = web_key(SHA_A, SHA_B, "wd1")

    def crashing_run():
        store.write_web(k2, ragged_web(np.random.default_rng(4)))
        raise RuntimeError("worker lost")

    with pytest.raises(RuntimeError):
        crashing_run()
    reader = MotionStore(str(tmp_path / "s"), read_only=True)
    assert current_id(reader) == g1.id
    assert [w["key"] for w in load_generation(reader).webs] == [k1]
    reader.read_web_arrays(k1)  # still readable
    # the next run resumes: the complete object from the crashed run is reused as cached
    assert store.has(k2)
    g2 = _gen(store, [k1, k2])
    g2.parent = g1.id
    commit(store, g2)
    assert current_id(store) == g2.id and generation_ids(store) == sorted([g1.id, g2.id])
    assert load_generation(store, g1.id).webs == g1.webs  # old generations stay readable
    with pytest.raises(PermissionError):
        commit(reader, _gen(reader, []))


def test_commit_refuses_missing_objects(tmp_path):
    store = MotionStore(str(tmp_path / "s"))
    with pytest.raises(RuntimeError, match="missing"):
        commit(store, _gen(store, [web_key(SHA_A, SHA_B, "nope")]))
    assert current_id(store) is None


def test_pointer_is_atomic_json(tmp_path):
    store = MotionStore(str(tmp_path / "s"))
    g = _gen(store, [])
    commit(store, g)
    data = json.loads((tmp_path / "s" / "current").read_text())
    assert data["generation"] == g.id
    assert not list((tmp_path / "s").glob("current.tmp-*"))


def test_gc_keeps_listed_objects(tmp_path):
    store = MotionStore(str(tmp_path / "s"))
    rng = np.random.default_rng(5)
    k_old = web_key(SHA_A, SHA_B, "wd0")
    k_new = web_key(SHA_A, SHA_B, "wd1")
    store.write_web(k_old, ragged_web(rng))
    commit(store, _gen(store, [k_old]))
    store.write_web(k_new, ragged_web(rng))
    commit(store, _gen(store, [k_new]))
    assert gc(store, keep=1) == [k_old]
    assert store.has(k_new) and not store.has(k_old)
    assert len(generation_ids(store)) == 1
