"""The web records of a manifest as columns (store/webtable.py) and the per-clip index StoreWebs
builds over them in numpy (store/webs.py), against the records themselves and the dict-filling
loop they replace (tests/naive.webs_by_clip)."""

from __future__ import annotations

import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from motionweb.store.generations import Generation, load_generation
from motionweb.store.webs import StoreWebs
from motionweb.store.webtable import WebTable
from motionweb.store.zarr_store import MotionStore, new_id, now_iso
from naive import webs_by_clip


def records(n_clips: int, pairs: list[tuple[int, int]]) -> list[dict]:
    """Web records shaped as the index writes them (flows/index.py)."""
    out = []
    for i, (a, b) in enumerate(pairs):
        sa, sb = f"{a:02d}" * 32, f"{b:02d}" * 32
        out.append({"chunk": f"c{a % 3}", "a": f"cat{a % 3}/clip_{a}.bvh", "b": f"cat{b % 3}/clip_{b}.bvh",
                    "a_sha": sa, "b_sha": sb, "key": f"webs/{sa[:2]}/{sa}-{sb}/abc{i}", "cells": 100 * a + b,
                    "self": a == b, "computed": bool(i % 2), "n_chains": i % 5, "n_bridges": 2 * i,
                    "rate": 30.0, "shape": [40 + a, 50 + b]})
    return out


def test_a_table_gives_back_the_records_it_holds():
    recs = records(6, [(a, b) for a in range(6) for b in range(a, 6)])
    recs[3] = {k: v for k, v in recs[3].items() if k != "n_chains"}  # a field some records lack
    recs[4]["note"] = "é, not ASCII"
    recs[5]["rate"] = 60  # an int among floats
    t = WebTable(recs)
    assert len(t) == len(recs)
    assert list(t) == recs and t == recs
    assert t[-1] == recs[-1] and t[2:5] == recs[2:5]
    assert "n_chains" not in t[3] and t[4]["note"] == "é, not ASCII"
    assert type(t[0]["self"]) is bool and type(t[0]["cells"]) is int and type(t[0]["shape"]) is list
    t[0]["a"] = "changed"
    assert t[0]["a"] == recs[0]["a"]  # a record is a copy
    with pytest.raises(IndexError):
        t[len(recs)]
    values, codes = t.strings("a")
    assert [values[c] for c in codes] == [r["a"] for r in recs]
    keys, kcodes = t.strings("key")
    assert [keys[c] for c in kcodes] == [r["key"] for r in recs]
    assert WebTable([]) == [] and list(WebTable([])) == []


def test_a_table_is_a_fraction_of_the_dicts():
    recs = records(60, [(a, b) for a in range(60) for b in range(a, 60)])

    def size(obj, seen=None) -> int:
        seen = set() if seen is None else seen
        if id(obj) in seen:
            return 0
        seen.add(id(obj))
        n = sys.getsizeof(obj)
        if isinstance(obj, dict):
            n += sum(size(k, seen) + size(v, seen) for k, v in obj.items())
        elif isinstance(obj, list):
            n += sum(size(v, seen) for v in obj)
        return n

    assert WebTable(recs).nbytes * 4 < size(recs)


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 9).flatmap(lambda n: st.tuples(
    st.just(n),
    st.lists(st.tuples(st.integers(0, n + 1), st.integers(0, n + 1)), max_size=40),
    st.lists(st.sampled_from(["walk", "run", ""]), min_size=n, max_size=n),
    st.sampled_from([None, "walk", "run", "", "nope"]))))
def test_store_webs_index_each_clip_as_the_dict_loop_did(tmp_path_factory, case):
    """Any pairs (self pairs, repeated pairs, clips outside the clip list), any categories."""
    n, pairs, cats, category = case
    recs = records(n + 2, pairs)
    clips = [{"path": f"cat{i % 3}/clip_{i}.bvh", "category": cats[i]} for i in range(n)]
    gen = Generation("g", "t", clips=clips, webs=recs)
    store = MotionStore(str(tmp_path_factory.mktemp("s")))
    want = webs_by_clip(recs, {c["path"]: c["category"] for c in clips}, category)
    for g in (gen, Generation("g", "t", clips=clips, webs=WebTable(recs))):  # type: ignore[arg-type]
        sw = StoreWebs(store, g, category)
        assert list(sw) == list(want)
        assert len(sw) == len(want)
        assert {c: sw.records_of(c) for c in sw} == want
        assert sorted(r["key"] for r in sw.records()) == sorted({r["key"] for rs in want.values() for r in rs})
        assert "cat0/clip_999.bvh" not in sw
        with pytest.raises(KeyError):
            sw.records_of("cat0/clip_999.bvh")


def test_a_lean_generation_holds_the_same_records(tmp_path):
    recs = records(5, [(a, b) for a in range(5) for b in range(a, 5)])
    clips = [{"path": f"cat{i % 3}/clip_{i}.bvh", "category": "x"} for i in range(5)]
    store = MotionStore(str(tmp_path / "store"))
    gid = new_id()  # the manifest as commit writes it (its objects are not needed here)
    store.write_json(f"generations/{gid}.json", Generation(gid, now_iso(), completed=now_iso(), clips=clips, webs=recs,
                                                           checksums={"k": "v"}).to_dict())
    full = load_generation(store, gid)
    lean = load_generation(store, gid, lean=True)
    assert isinstance(lean.webs, WebTable) and list(lean.webs) == full.webs == recs
    assert lean.clips == full.clips and lean.checksums == {} and full.checksums == {"k": "v"}
    assert np.array_equal(StoreWebs(store, lean)._ids, StoreWebs(store, full)._ids)


@pytest.mark.parametrize("dump", [{"indent": 1, "sort_keys": True}, {}, {"separators": (",", ":")}, {"indent": "\t"}])
def test_a_manifest_parses_as_json_does(dump):
    import json

    from motionweb.store.webtable import parse_manifest

    recs = records(4, [(0, 1), (1, 1), (2, 3)])
    doc = {"id": "g", "clips": [{"path": "a"}], "webs": recs, "checksums": {"k": "v", "w": "x"},
           "stats": {"nested": [1, {"webs": []}]}, "empty": {}, "list": []}
    text = json.dumps(doc, **dump)
    got = parse_manifest(text)
    assert isinstance(got["webs"], WebTable) and list(got["webs"]) == recs
    assert "checksums" not in got
    assert {k: v for k, v in got.items() if k != "webs"} == {k: v for k, v in doc.items() if k not in ("webs", "checksums")}
    assert parse_manifest(text, skip=())["checksums"] == doc["checksums"]
    assert list(parse_manifest(json.dumps({"webs": []}))["webs"]) == []
    assert parse_manifest("[1, 2]") == [1, 2]
    for bad in (text[:-1], text[: len(text) // 2], text + "x", text.replace(":", "", 1), '{"webs": [1]}', "{"):
        with pytest.raises(ValueError):
            parse_manifest(bad)
