"""The store on an S3-compatible endpoint (issue 25, part 6): the index flow, search (the query flow
and the service), an unchanged re-index and an interrupted commit with ``store.path: s3://bucket/...``.

The endpoint is **moto's server mode, an emulator** of the S3 API (``ThreadedMotoServer`` in this
process, on loopback, with fake credentials): it proves that the store speaks S3 through s3fs and
zarr's ``FsspecStore`` (no rename, no directories, listings by prefix, one PUT per object, the
endpoint and credentials taken from the standard AWS environment variables, in this process and in
separately started Dask workers alike). It does not prove S3's consistency, latency, throughput,
request limits or multipart behaviour on large objects, nor MinIO's or any other vendor's quirks:
moto answers every request at once from memory. The commit's atomicity rests on one property of
real S3 that moto also has: a PUT replaces an object whole, and a reader sees the old or the new
object, never part of one (README, "A commit on an object store").

The tests skip, with the reason, only when ``moto[server]`` or ``s3fs`` cannot be imported; both
are in the ``dev`` extra, so CI runs them.
"""

from __future__ import annotations

import logging
import shutil
import uuid
from pathlib import Path

import numpy as np
import pytest
import yaml

moto_server = pytest.importorskip("moto.server", reason="moto[server] (the dev extra) is not installed")
pytest.importorskip("s3fs", reason="s3fs (the dev extra) is not installed")

BUCKET = "motionweb-test"


@pytest.fixture(scope="module")
def s3_endpoint():
    """moto's S3 emulator on a free loopback port, with one bucket; its URL. The endpoint and fake
    credentials are set the way a user of a real S3 or MinIO sets them (``AWS_ENDPOINT_URL_S3``,
    ``AWS_ACCESS_KEY_ID``, ``AWS_SECRET_ACCESS_KEY``), so that every process started from here
    (Dask workers) finds them too; restored afterwards."""
    import fsspec
    import s3fs

    logging.getLogger("werkzeug").setLevel(logging.ERROR)  # one line per request otherwise
    server = moto_server.ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
    server.start()
    host, port = server.get_host_and_port()
    url = f"http://{host}:{port}"
    mp = pytest.MonkeyPatch()
    for var, value in [("AWS_ENDPOINT_URL_S3", url), ("AWS_ACCESS_KEY_ID", "testing"),
                       ("AWS_SECRET_ACCESS_KEY", "testing"), ("AWS_DEFAULT_REGION", "us-east-1")]:
        mp.setenv(var, value)
    for var in ("AWS_PROFILE", "AWS_SESSION_TOKEN", "AWS_ENDPOINT_URL", "FSSPEC_S3"):
        mp.delenv(var, raising=False)
    s3fs.S3FileSystem.clear_instance_cache()  # none bound to another endpoint
    fsspec.filesystem("s3").mkdir(BUCKET)
    try:
        yield url
    finally:
        s3fs.S3FileSystem.clear_instance_cache()
        mp.undo()
        server.stop()


def _s3_url(name: str) -> str:
    return f"s3://{BUCKET}/{name}-{uuid.uuid4().hex[:8]}"


# ------------------------------------------------------------------------- the store alone
def test_objects_listing_and_pointer_on_s3(s3_endpoint) -> None:
    """Objects written by one store instance are seen by another (no stale listing), the pointer
    is one object written by one PUT (no temporary files, nothing renamed), and a commit whose
    pointer write fails leaves the previous generation current and readable."""
    import fsspec
    from fixtures import ragged_web
    from motionweb.store import generations as G
    from motionweb.store.keys import web_key
    from motionweb.store.zarr_store import MotionStore, new_id, now_iso

    url = _s3_url("unit")
    writer, reader = MotionStore(url), MotionStore(url, read_only=True)
    k1 = web_key("a" * 64, "a" * 64, "wd1")
    assert not reader.has(k1) and G.current_id(reader) is None  # listed once, empty
    writer.write_web(k1, ragged_web(np.random.default_rng(3)))
    assert reader.has(k1) and reader.verify(k1) is None  # listed again: the new shard is seen
    g1 = G.Generation(id=new_id(), created=now_iso(), webs=[{"a": "x", "b": "y", "key": k1}])
    G.commit(writer, g1)
    assert G.check_current(reader) == g1.id and G.generation_ids(reader) == [g1.id]
    sig = G.pointer_signature(reader)
    fs = fsspec.filesystem("s3")
    root = url.removeprefix("s3://")
    assert sorted(p.rsplit("/", 1)[1] for p in fs.ls(root, detail=False, refresh=True)) == [
        "current", "generations", "webs", "zarr.json"]

    k2 = web_key("a" * 64, "b" * 64, "wd1")
    writer.write_web(k2, ragged_web(np.random.default_rng(4)))
    g2 = G.Generation(id=new_id(), created=now_iso(), parent=g1.id,
                      webs=[{"a": "x", "b": "y", "key": k1}, {"a": "x", "b": "z", "key": k2}])
    real = G._point_to

    def broken(store, gen):
        raise ConnectionError("the endpoint went away before the pointer's PUT")

    G._point_to = broken
    try:
        with pytest.raises(ConnectionError):
            G.commit(writer, g2)
    finally:
        G._point_to = real
    assert G.check_current(reader) == g1.id and G.pointer_signature(reader) == sig
    assert [w["key"] for w in G.load_generation(reader).webs] == [k1]
    reader.read_web_arrays(k1)
    assert G.generation_ids(reader) == sorted([g1.id, g2.id])  # written, never published
    G.commit(writer, g2)
    assert G.check_current(reader) == g2.id and G.pointer_signature(reader) != sig
    assert G.gc(writer, keep=1) == [f"generations/{g1.id}.json"]
    assert G.generation_ids(reader) == [g2.id] and reader.verify(k2) is None


# ------------------------------------------------------------------------------ the flows
def _corpus(root: Path) -> Path:
    from motionweb.store.demo.corpus import write_demo_corpus

    write_demo_corpus(root, seed=7, variants_per_category=2, fps=30.0)
    for d in root.iterdir():
        if d.name not in ("walk", "jump"):
            shutil.rmtree(d)
    return root


def _config(tmp_path: Path, name: str, store: str, dask: dict, corpus: str = "corpus") -> Path:
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump({"corpus": {"path": corpus, "length_unit": "m"},
                                    "features": {"rates": [10.0, 30.0]}, "store": {"path": store},
                                    "dask": dask, "output": f"out-{name}"}))
    return path


def test_index_search_reindex_and_interrupted_commit_on_s3(prefect_harness, s3_endpoint, tmp_path: Path,
                                                           monkeypatch) -> None:
    from motionweb.flows.commands.requests import QueryRequest
    from motionweb.flows.config import load_config
    from motionweb.flows.index import index_library
    from motionweb.flows.query import query
    from motionweb.store import generations as G
    from motionweb.store.zarr_store import MotionStore

    _corpus(tmp_path / "corpus")
    s3_url = _s3_url("store")
    cfgs = {"s3": load_config(_config(tmp_path, "s3", s3_url, {"processes": False})),
            "local": load_config(_config(tmp_path, "local", "store-local", {"processes": False}))}
    assert cfgs["s3"].store.path == s3_url  # an fsspec URL is not made a local path
    summaries = {name: index_library(cfg) for name, cfg in cfgs.items()}
    for s in summaries.values():
        assert s["pairs_computed"] == s["pairs"] > 0 and not s["broken"], s
    assert summaries["s3"]["store_bytes"] > 0
    stores = {name: MotionStore(cfg.store.path, read_only=True) for name, cfg in cfgs.items()}
    gens = {name: G.load_generation(store) for name, store in stores.items()}
    assert gens["s3"].config != gens["local"].config  # the store's and output's locations differ
    gens["local"].config = gens["s3"].config
    assert G.same_content(gens["s3"], gens["local"])  # clips, keys, checksums (the bytes), parameters
    assert gens["s3"].checksums == gens["local"].checksums and gens["s3"].checksums
    assert not G.verify_generation(stores["s3"], gens["s3"])  # every object read back whole
    for w in gens["s3"].webs[:3]:
        a, b = stores["s3"].read_web_arrays(w["key"])[0], stores["local"].read_web_arrays(w["key"])[0]
        assert a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)

    # a search of the S3 store answers what the same search of the local one does
    def search(cfg, out: str) -> dict:
        return query(cfg, QueryRequest(clip="walk/walk_00.bvh", start=0.5, end=1.5, quantile=0.8,
                                       out=str(tmp_path / out)))

    found = {name: search(cfg, f"q-{name}") for name, cfg in cfgs.items()}
    assert found["s3"]["generation"] == gens["s3"].id and found["s3"]["matches"]
    assert found["s3"]["matches"] == found["local"]["matches"]

    # the service (`motionweb app`: its search workers are processes of their own, which open the
    # store from the environment too) answers from the S3 store what it answers from the local one
    from fastapi.testclient import TestClient
    from motionweb.flows.app.api import create_app
    from motionweb.flows.app.engine import Engine

    answers = {}
    for name, cfg in cfgs.items():
        engine = Engine(cfg, warm=False)
        try:
            answers[name] = TestClient(create_app(engine)).post(
                "/api/search", json={"clip": "walk_00", "start": 0.5, "end": 1.5, "quantile": 0.8}).json()
        finally:
            engine.close()
    assert answers["s3"]["generation"] == gens["s3"].id and answers["s3"]["matches"], answers["s3"]
    assert answers["s3"]["epsilon"] == answers["local"]["epsilon"]
    assert answers["s3"]["matches"] == answers["local"]["matches"]

    # nothing changed: no new generation, nothing computed
    again = index_library(cfgs["s3"])
    assert again["generation"] == gens["s3"].id and again["pairs_computed"] == 0
    assert G.generation_ids(stores["s3"]) == [gens["s3"].id]

    # a run whose commit is interrupted at the pointer's PUT leaves the previous generation current
    (tmp_path / "corpus" / "jump" / "jump_01.bvh").unlink()  # the next generation lists fewer clips

    def interrupted(store, gen):
        raise ConnectionError("the endpoint went away before the pointer's PUT")

    monkeypatch.setattr(G, "_point_to", interrupted)
    with pytest.raises(ConnectionError):
        index_library(cfgs["s3"])
    monkeypatch.undo()
    reader = MotionStore(s3_url, read_only=True)
    assert G.check_current(reader) == gens["s3"].id
    assert len(G.generation_ids(reader)) == 2  # the interrupted run's manifest: written, not published
    assert not G.verify_generation(reader, G.load_generation(reader))
    assert search(cfgs["s3"], "q-after")["matches"] == found["s3"]["matches"]
    # the next run commits (the unpublished manifest, older than the new current one, is kept by
    # gc like a committed one: it is complete and intact, only never named by the pointer)
    done = index_library(cfgs["s3"])
    assert done["generation"] != gens["s3"].id and done["pairs_computed"] == 0
    assert G.check_current(reader) == done["generation"]
    assert len(G.load_generation(reader).clips) == len(gens["s3"].clips) - 1
    assert len(G.generation_ids(reader)) == 3 and G.generation_ids(reader)[-1] == done["generation"]


def test_index_on_a_separately_started_cluster_into_s3(prefect_harness, s3_endpoint, external_cluster: str,
                                                       tmp_path: Path) -> None:
    """``dask scheduler`` and ``dask worker`` processes (started after the endpoint's environment
    is set, as a user's would be) write the webs into the S3 store: the same bytes as a local
    cluster's into a local folder."""
    from motionweb.flows.config import load_config
    from motionweb.flows.index import index_library
    from motionweb.store.generations import load_generation
    from motionweb.store.zarr_store import MotionStore

    _corpus(tmp_path / "corpus")
    gens = {}
    for name, store, dask in (("remote", _s3_url("remote"), {"address": external_cluster}),
                              ("local", "store-local", {"processes": False})):
        cfg = load_config(_config(tmp_path, name, store, dask))
        summary = index_library(cfg)
        assert summary["pairs_computed"] == summary["pairs"] > 0 and not summary["broken"], summary
        gens[name] = load_generation(MotionStore(cfg.store.path, read_only=True))
    assert sorted(w["key"] for w in gens["remote"].webs) == sorted(w["key"] for w in gens["local"].webs)
    assert gens["remote"].checksums == gens["local"].checksums
