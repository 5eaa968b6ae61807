"""The index flow (design §1, §9, §10): planning as plain functions, then a few real flow runs.

Flow runs use Prefect's test harness once per session with heartbeats off (they only slow short runs) and a
small synthetic corpus (two categories, a broken file, one clip with another skeleton).
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

for _k, _v in {
    "PREFECT_SERVER_ANALYTICS_ENABLED": "false",
    "PREFECT_LOGGING_LEVEL": "WARNING",
    "PREFECT_LOGGING_TO_API_WHEN_MISSING_FLOW": "ignore",
    "PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS": "90",
    "DASK_LOGGING__DISTRIBUTED": "warning",
}.items():
    os.environ.setdefault(_k, _v)

import numpy as np
import pytest
from motionweb.flows.config import Config, resolve_paths
from motionweb.flows.index import (
    Chunk,
    PairJob,
    balance_batches,
    build_generation,
    format_summary,
    index_library,
    plan_chunk,
    plan_chunks,
    plan_pairs,
    skeleton_groups,
)
from motionweb.flows.runtime.workers import web_counts
from motionweb.store.bvh import write_bvh
from motionweb.store.catalog import Catalog, ClipEntry, ScanError
from motionweb.store.generations import current_id, load_generation
from motionweb.store.keys import web_digest
from motionweb.store.kinematics import quat_from_euler
from motionweb.store.motion import Motion, Skeleton
from motionweb.store.zarr_store import MotionStore


# ------------------------------------------------------------------------------ plain functions
def entry(path: str, sha: str, category: str = "walk", frames: int = 61, fps: float = 30.0,
          skeleton: str = "S1") -> ClipEntry:
    return ClipEntry(path=path, abs_path="/x/" + path, category=category, sha256=sha * 64, format="bvh",
                     fps=fps, frames=frames, duration=(frames - 1) / fps, skeleton=skeleton, n_joints=3,
                     unit="m")


def test_plan_chunks_by_category_and_unsplit():
    es = [entry("walk/b.bvh", "2"), entry("run/a.bvh", "1", "run"), entry("walk/a.bvh", "3")]
    chunks = plan_chunks(es, "category")
    assert [c.name for c in chunks] == ["run", "walk"]
    assert [e.path for e in chunks[1].clips] == ["walk/a.bvh", "walk/b.bvh"]
    (one,) = plan_chunks(es, "none")
    assert one.name == "all" and len(one.clips) == 3
    assert plan_chunks([], "none") == []


def test_pair_plan_canonical_and_skeleton_compatible():
    clips = (entry("walk/a.bvh", "3"), entry("walk/b.bvh", "1"), entry("walk/c.bvh", "2"),
             entry("walk/odd.bvh", "4", skeleton="S2"))
    chunk = Chunk("walk", clips)
    rep = skeleton_groups(chunk)
    assert rep.majority == "S1" and rep.minority == ["walk/odd.bvh"]
    jobs = plan_pairs(chunk, "wd", 30.0)
    # 3 compatible clips: 3 self pairs + 3 cross pairs; the odd skeleton only with itself
    assert len(jobs) == 7
    for j in jobs:
        assert j.a.sha256 <= j.b.sha256 and j.a.skeleton == j.b.skeleton
        assert j.self_pair == (j.a.sha256 == j.b.sha256)
        assert j.cells == 61 * 61
    odd = [j for j in jobs if "odd" in j.a.path or "odd" in j.b.path]
    assert len(odd) == 1 and odd[0].self_pair
    # keys do not depend on the order of the clips
    assert {j.key for j in plan_pairs(Chunk("walk", clips[::-1]), "wd", 30.0)} == {j.key for j in jobs}


def test_balance_batches_by_cells():
    rng = np.random.default_rng(0)
    jobs = [PairJob("c", entry(f"a{i}", "1"), entry(f"b{i}", "2"), f"k{i}", int(c), False)
            for i, c in enumerate(rng.integers(1_000, 2_000_000, size=200))]
    batches = balance_batches(jobs, 8)
    assert len(batches) == 8
    assert sorted(j.key for b in batches for j in b) == sorted(j.key for j in jobs)
    loads = [sum(j.cells for j in b) for b in batches]
    assert max(loads) - min(loads) <= max(j.cells for j in jobs)
    assert max(loads) / (sum(loads) / 8) < 1.05
    assert balance_batches(jobs[:3], 8) == [[j] for j in sorted(jobs[:3], key=lambda j: -j.cells)]


def test_web_counts_from_ragged_arrays():
    arrays = {"paths_offsets": np.array([0, 4, 9, 9]), "paths_cells": np.zeros((9, 2)),
              "bridges_offsets": np.array([0, 3])}
    assert web_counts(arrays) == {"n_chains": 3, "n_bridges": 1}


def test_generation_manifest_lists_broken_and_drops_their_pairs():
    cfg = Config()
    es = [entry("walk/a.bvh", "1"), entry("walk/b.bvh", "2"), entry("walk/c.bvh", "3")]
    cat = Catalog(root="/x", entries=es, errors=[ScanError("walk/bad.bvh", "truncated")])
    plan = plan_chunk(Chunk("walk", tuple(es)), cfg, has=lambda k: False, has_features=lambda s: False)
    assert len(plan.todo) == 6 and len(plan.features_todo) == 3
    results = {j.key: {"key": j.key, "n_chains": 2, "n_bridges": 1} for j in plan.todo}
    ab = next(j for j in plan.todo if {j.a.path, j.b.path} == {"walk/a.bvh", "walk/b.bvh"})
    results[ab.key] = {"key": ab.key, "error": "ValueError: boom"}
    gen = build_generation(cfg, cat, [plan], results, {"3" * 64: "cannot read"}, None, {"catalog_s": 0.1})
    assert {b["path"] for b in gen.broken} == {"walk/bad.bvh", "walk/c.bvh", "walk/a.bvh x walk/b.bvh"}
    assert [c["path"] for c in gen.clips] == ["walk/a.bvh", "walk/b.bvh"]
    assert len(gen.webs) == 2 and gen.stats["chains"] == 4 and gen.stats["bridges"] == 2
    assert gen.params["webs"] == web_digest(cfg) and gen.versions["numpy"] == np.__version__
    text = format_summary({**gen.stats, "generation": gen.id, "store": "s", "params": gen.params,
                           "wall_s": 1.0, "store_bytes": 10, "broken": gen.broken, "skeleton_minority": []})
    assert "walk/bad.bvh: truncated" in text and "pairs 2" in text


# ------------------------------------------------------------------------------- corpus helpers
def chain_motion(seconds: float, freq: float, phase: float, n_joints: int = 4, fps: float = 30.0) -> Motion:
    """A swinging chain walking forward: periodic, so webs have chains of local minima."""
    names = tuple(f"j{i}" for i in range(n_joints))
    sk = Skeleton(names=names, parents=np.arange(n_joints) - 1,
                  offsets=np.vstack([[0, 0, 0]] + [[0.0, -0.3, 0.05]] * (n_joints - 1)),
                  channels=(("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation"),)
                  + (("Zrotation", "Xrotation", "Yrotation"),) * (n_joints - 1))
    t = np.arange(int(seconds * fps)) / fps
    ang = np.zeros((len(t), n_joints, 3))
    for j in range(n_joints):
        ang[:, j, 1] = 35 * np.sin(2 * np.pi * freq * t + phase + 0.7 * j)
        ang[:, j, 0] = 10 * np.cos(2 * np.pi * freq * t + phase)
    rot = quat_from_euler(ang, "ZXY")
    root = np.stack([0.8 * t, 1.0 + 0.05 * np.sin(4 * np.pi * freq * t), 0.1 * t], axis=1)
    return Motion(skeleton=sk, fps=fps, root_positions=root, rotations=rot)


def write_corpus(root: Path) -> Path:
    (root / "walk").mkdir(parents=True)
    (root / "run").mkdir(parents=True)
    write_bvh(chain_motion(2.0, 1.0, 0.0), root / "walk" / "w1.bvh")
    write_bvh(chain_motion(2.5, 1.1, 0.5), root / "walk" / "w2.bvh")
    write_bvh(chain_motion(1.5, 0.9, 1.0), root / "walk" / "w3.bvh")
    write_bvh(chain_motion(1.5, 1.0, 0.2, n_joints=3), root / "walk" / "odd.bvh")  # other skeleton
    write_bvh(chain_motion(2.0, 2.0, 0.0), root / "run" / "r1.bvh")
    write_bvh(chain_motion(1.5, 2.2, 0.3), root / "run" / "r2.bvh")
    (root / "run" / "broken.bvh").write_text("HIERARCHY\nROOT hips\n{\n  OFFSET 0 0\n")
    return root


def make_config(tmp: Path, corpus: Path, store: str, **overrides) -> Config:
    data = {
        "corpus": {"path": str(corpus), "length_unit": "m"},
        "features": {"rates": [10.0, 20.0]},
        "store": {"path": store},
        "dask": {"processes": False, "n_workers": 2},
        "output": str(tmp / "out"),
    }
    for section, values in overrides.items():
        data[section] = {**data.get(section, {}), **values}
    return resolve_paths(Config.model_validate(data), tmp)


# ----------------------------------------------------------------------------------- flow runs
@pytest.fixture(scope="module")
def indexed(prefect_harness, tmp_path_factory):
    """A corpus indexed once: (tmp dir, corpus, config, first summary)."""
    tmp = tmp_path_factory.mktemp("index")
    corpus = write_corpus(tmp / "corpus")
    cfg = make_config(tmp, corpus, str(tmp / "store"))
    summary = index_library(cfg)
    return tmp, corpus, cfg, summary


def test_flow_end_to_end(indexed):
    _tmp, _corpus, cfg, s = indexed
    # walk: 3 compatible clips (6 pairs) + odd skeleton (self pair); run: 2 clips (3 pairs)
    assert s["chunks"] == 2 and s["clips"] == 6
    assert s["pairs"] == 10 and s["pairs_computed"] == 10 and s["pairs_cached"] == 0, s["broken"]
    assert s["chains"] > 0
    assert [b["path"] for b in s["broken"]] == ["run/broken.bvh"]
    assert s["skeleton_minority"] == ["walk/odd.bvh"]
    store = MotionStore(cfg.store.path, read_only=True)
    gen = load_generation(store)
    assert gen.id == s["generation"] and current_id(store) == gen.id
    assert gen.broken[0]["path"] == "run/broken.bvh" and gen.skeleton[0]["minority"] == ["walk/odd.bvh"]
    assert gen.versions["zarr"] and gen.timings["catalog_s"] >= 0 and gen.config["store"]["path"]
    rec, _ = gen.web_for("walk/w1.bvh", "walk/w2.bvh")
    web = store.read_web(rec["key"])
    assert tuple(int(x) for x in np.ravel(web.shape)) == tuple(rec["shape"])
    assert gen.web_for("walk/w1.bvh", "run/r1.bvh") is None  # chunks are not crossed
    writer = MotionStore(cfg.store.path)  # each web's record names the shard it is in (readers take in that one)
    assert all(w["shard"] == writer.web_shard(w["key"]) for w in gen.webs)
    assert gen.web_for("walk/w1.bvh", "walk/odd.bvh") is None  # incompatible skeletons
    assert "run/broken.bvh" in format_summary(s)


def test_incremental_rerun_change_remove_and_params(indexed):
    _tmp, corpus, cfg, first = indexed
    store = MotionStore(cfg.store.path)
    # nothing changed: every pair from the cache
    s2 = index_library(cfg)
    assert s2["pairs_computed"] == 0 and s2["pairs_cached"] == 10 and s2["features_computed"] == 0
    assert s2["chains"] == first["chains"]
    # change one clip (w1) and remove another (r2)
    write_bvh(chain_motion(2.0, 1.0, 0.4), corpus / "walk" / "w1.bvh")
    (corpus / "run" / "r2.bvh").unlink()
    s3 = index_library(cfg)
    assert s3["pairs_computed"] == 3  # w1×w1, w1×w2, w1×w3
    assert s3["features_computed"] == 1
    assert s3["pairs"] == 8 and s3["pairs_cached"] == 5
    gen = load_generation(store)
    assert all("run/r2.bvh" not in (w["a"], w["b"]) for w in gen.webs)
    assert all(w["shard"] == store.web_shard(w["key"]) for w in gen.webs)  # cached ones and new ones
    before = {w["shard"] for w in load_generation(store, first["generation"]).webs}
    assert sum(w["shard"] not in before for w in gen.webs) == 3  # the 3 computed now are in new shards
    assert gen.parent == s2["generation"]
    # another matchweb config: a new parameter hash, nothing mixed with the old webs
    cfg2 = cfg.model_copy(update={"matchweb": replace_mw(cfg, valid_a=0.3)})
    s4 = index_library(cfg2)
    assert s4["params"]["webs"] != s3["params"]["webs"] and s4["params_changed"]
    assert s4["pairs_computed"] == s4["pairs"] == 8 and s4["features_computed"] == 0
    new, old = load_generation(store), load_generation(store, s3["generation"])
    assert not {w["key"] for w in new.webs} & {w["key"] for w in old.webs}
    assert all(store.has(w["key"]) for w in old.webs)  # the old generation stays readable


def test_a_manifest_without_web_shards_gets_them_on_the_next_run(prefect_harness, tmp_path):
    """A store indexed before web records named their shard: the next run with nothing changed
    commits one generation that names them (readers then take in only those shards), the run
    after it commits nothing."""
    from motionweb.store.generations import Generation, commit
    from motionweb.store.zarr_store import new_id

    corpus = write_corpus(tmp_path / "corpus")
    cfg = make_config(tmp_path, corpus, str(tmp_path / "store"))
    first = index_library(cfg)
    store = MotionStore(cfg.store.path)
    old = load_generation(store)
    d = old.to_dict() | {"id": new_id()}
    d["webs"] = [{k: v for k, v in w.items() if k != "shard"} for w in old.webs]
    commit(store, Generation.from_dict(d))
    assert all("shard" not in w for w in load_generation(store).webs)
    s2 = index_library(cfg)
    assert s2["pairs_computed"] == 0 and s2["generation"] != d["id"] and s2["generation"] != first["generation"]
    gen = load_generation(store)
    assert gen.id == s2["generation"] and all(w["shard"] == store.web_shard(w["key"]) for w in gen.webs)
    s3 = index_library(cfg)
    assert s3["pairs_computed"] == 0 and s3["generation"] == s2["generation"]


def replace_mw(cfg: Config, **kw):
    return cfg.matchweb.model_copy(update=kw)


def test_flow_on_distributed_scheduler(prefect_harness, tmp_path):
    """The same flow on a real dask.distributed scheduler with a worker process on loopback."""
    from distributed import LocalCluster

    corpus = tmp_path / "corpus"
    (corpus / "walk").mkdir(parents=True)
    write_bvh(chain_motion(1.5, 1.0, 0.0), corpus / "walk" / "a.bvh")
    write_bvh(chain_motion(1.5, 1.2, 0.3), corpus / "walk" / "b.bvh")
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None) as cluster:
        cfg = make_config(tmp_path, corpus, str(tmp_path / "store"), dask={"address": cluster.scheduler_address})
        s = index_library(cfg)
    assert s["pairs"] == s["pairs_computed"] == 3 and s["clips"] == 2
    gen = load_generation(MotionStore(cfg.store.path))
    assert {(w["a"], w["b"]) for w in gen.webs} >= {("walk/a.bvh", "walk/a.bvh"), ("walk/b.bvh", "walk/b.bvh")}


def test_flow_with_fsspec_store(prefect_harness, tmp_path):
    """Store path as an fsspec URL (memory://) instead of a local folder."""
    corpus = tmp_path / "corpus"
    (corpus / "walk").mkdir(parents=True)
    write_bvh(chain_motion(1.0, 1.0, 0.0), corpus / "walk" / "a.bvh")
    shutil.copy(corpus / "walk" / "a.bvh", corpus / "walk" / "copy.bvh")  # identical bytes: one web key
    cfg = make_config(tmp_path, corpus, f"memory://mw-{tmp_path.name}/store")
    s = index_library(cfg)
    assert s["pairs"] == 3 and s["pairs_computed"] == 1
    assert current_id(MotionStore(cfg.store.path)) == s["generation"]


def test_plot_web_figure(tmp_path):
    """plot-web: the grid at the working rate with chains and bridges, written to a PNG."""
    from motionweb.flows.plots import plot_web

    corpus = write_corpus(tmp_path / "corpus")
    cfg = make_config(tmp_path, corpus, str(tmp_path / "store"))
    rep = plot_web(cfg, "walk/w1.bvh", "w2", tmp_path / "web.png")
    assert rep.rate == 20.0 and rep.shape == (40, 50) and rep.chains > 0 and rep.minima > 0
    assert (tmp_path / "web.png").stat().st_size > 10_000
    with pytest.raises(ValueError, match="different skeletons"):
        plot_web(cfg, "w1", "odd", tmp_path / "x.png")


def test_shortlist_index_keeps_exact_webs_of_its_pairs(prefect_harness, tmp_path):
    """``chunk_by: none`` with ``index.shortlist``: webs only for the shortlisted pairs, each
    byte-equal to the exact all-pairs index's web of that pair; every self pair kept; a changed
    clip gets its features and its pairs of the recomputed shortlist, the rest cached; a rerun
    with nothing changed computes nothing (the flow and the Prefect-free answer alike)."""
    from motionweb.flows.index import unchanged_summary

    corpus = write_corpus(tmp_path / "corpus")
    exact = make_config(tmp_path, corpus, str(tmp_path / "exact"), index={"chunk_by": "none"})
    short = make_config(tmp_path, corpus, str(tmp_path / "short"),
                        # hub_ratio 0: on 5 clips every pair is within 4 × a window's nearest; this test
                        # is about the flow (exact webs of the pairs kept), so a rule that leaves pairs out
                        index={"chunk_by": "none", "shortlist": {"enabled": True, "k": 1, "min_hits": 6,
                                                                 "hub_ratio": 0}})
    se, ss = index_library(exact), index_library(short)
    # 5 clips of one skeleton (15 pairs) + odd with itself
    assert se["pairs"] == 16 and [b["path"] for b in ss["broken"]] == ["run/broken.bvh"]
    assert ss["shortlist"]["candidates"] == 16 and ss["pairs"] == ss["shortlist"]["pairs"] < 16
    ge = load_generation(MotionStore(exact.store.path, read_only=True))
    gs = load_generation(MotionStore(short.store.path, read_only=True))
    assert gs.stats["shortlist"]["pairs"] == ss["pairs"] and gs.chunks[0]["shortlist"]["chunk"] == "all"
    exact_keys = {w["key"] for w in ge.webs}
    assert {w["key"] for w in gs.webs} < exact_keys
    assert {(w["a"], w["b"]) for w in gs.webs if w["self"]} == {(c["path"], c["path"]) for c in gs.clips}
    sa, sb = MotionStore(exact.store.path, read_only=True), MotionStore(short.store.path, read_only=True)
    for w in gs.webs:
        (xa, ta), (xb, tb) = sa.read_web_arrays(w["key"]), sb.read_web_arrays(w["key"])
        assert ta == tb and sorted(xa) == sorted(xb), w["key"]
        for name in xa:
            assert xa[name].dtype == xb[name].dtype and xa[name].tobytes() == xb[name].tobytes(), (w["key"], name)
    # nothing changed: nothing computed, the same generation, also without Prefect
    again = index_library(short)
    assert again["pairs_computed"] == 0 and again["generation"] == ss["generation"]
    assert again["shortlist"]["reused"] == 1 and not ss["shortlist"]["reused"]  # the same inputs: not recomputed
    quick = unchanged_summary(short)
    assert quick is not None and quick["generation"] == ss["generation"] and quick["pairs"] == ss["pairs"]
    # a changed clip: its features and the new shortlist's pairs with it, the others cached
    write_bvh(chain_motion(2.0, 1.0, 0.4), corpus / "walk" / "w1.bvh")
    assert unchanged_summary(short) is None
    s3 = index_library(short)
    g3 = load_generation(MotionStore(short.store.path, read_only=True))
    assert s3["features_computed"] == 1 and s3["shortlist"]["reused"] == 0
    w1 = next(c["sha256"] for c in g3.clips if c["path"] == "walk/w1.bvh")
    assert {w["key"] for w in g3.webs if w["computed"]} == {w["key"] for w in g3.webs if w1 in (w["a_sha"], w["b_sha"])}
    assert s3["pairs"] == g3.stats["shortlist"]["pairs"] and ("walk/w1.bvh", "walk/w1.bvh") in {
        (w["a"], w["b"]) for w in g3.webs}
