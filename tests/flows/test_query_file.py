"""A clip from outside the index as a query (``motionweb search --query-file``, tasks/query_clip.py,
issue 24): its webs, built on demand, are the webs the index stores for the same pair; a copy of an
indexed clip under another name finds the indexed query's matches; a demo walk and CMU trials left
out of the index retrieve their own category (real data, skipped without it)."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from motionweb.flows.commands.cli import app
from motionweb.flows.commands.requests import QueryRequest
from motionweb.flows.config import load_config
from motionweb.flows.query import FILE_PREFIX, committed_generation, indexed_config, plan_query, query
from motionweb.store.formats import read_motion
from motionweb.store.webs import StoreWebs
from motionweb.tasks.query_clip import clip_operands, query_clip_webs
from typer.testing import CliRunner

runner = CliRunner()


def same_web(a, b) -> bool:
    x, y = a.to_arrays(), b.to_arrays()
    return x.keys() == y.keys() and all(np.array_equal(x[k], y[k]) for k in x)


def test_webs_built_on_demand_are_the_index_webs(app_store: Path) -> None:
    """walk_01's webs against the other walks, built as for a clip from outside the index, equal
    the stored webs oriented with walk_01 as rows (either side of the index's hash order)."""
    cfg = load_config(app_store)
    store, gen = committed_generation(cfg.store.path)
    gen_cfg = indexed_config(gen)
    rec = next(c for c in gen.clips if c["path"] == "walk/walk_01.bvh")
    motion = read_motion(Path(gen_cfg.corpus.path) / rec["path"], unit="m")
    others = {c["path"]: c["sha256"] for c in gen.clips if c["category"] == "walk" and c["path"] != rec["path"]}
    assert len(others) == 2
    _, _, mine = clip_operands(motion, gen_cfg.features, gen_cfg.corpus.up_axis)
    fdig = gen.params["features"]
    built = query_clip_webs(motion, mine, others, lambda n: store.read_features(others[n], fdig), gen_cfg.matchweb)
    stored = dict(StoreWebs(store, gen, "walk")[rec["path"]])
    for name in others:
        assert same_web(built[name], stored[name]), name
    assert same_web(built[""], stored[rec["path"]])  # its self web
    with pytest.raises(ValueError, match="indexed as"):
        query_clip_webs(motion, mine, {rec["path"]: rec["sha256"]}, lambda n: None, gen_cfg.matchweb)


def test_a_copy_under_another_name_finds_the_indexed_querys_matches(app_store: Path, tmp_path: Path) -> None:
    cfg = load_config(app_store)
    copy = tmp_path / "renamed.bvh"
    shutil.copy(Path(cfg.corpus.path) / "walk" / "walk_00.bvh", copy)
    args = ["--start", "1.0", "--end", "2.5", "--quantile", "0.8"]
    a = runner.invoke(app, ["search", str(app_store), "--clip", "walk_00", *args, "--out", str(tmp_path / "a")])
    b = runner.invoke(app, ["search", str(app_store), "--query-file", str(copy), *args, "--out", str(tmp_path / "b")])
    assert a.exit_code == 0 and b.exit_code == 0, (a.output, b.output)
    table = [line for line in a.output.splitlines() if line.startswith(("rank", " ", "0", "1", "2", "3"))]
    assert table and table == [line for line in b.output.splitlines() if line in table]


def test_a_new_demo_walk_retrieves_walks(app_store: Path, tmp_path: Path) -> None:
    """A demo walk of another seed (not indexed): its webs are built on demand against the six
    indexed clips, and the query's matches are walks."""
    from motionweb.store.bvh import write_bvh
    from motionweb.store.demo.corpus import generate_clip

    walk, _ = generate_clip("walk", 0, 1234, 30.0)
    write_bvh(walk, tmp_path / "new_walk.bvh")
    cfg = load_config(app_store)
    request = QueryRequest(clip="new_walk.bvh", start=1.0, end=2.5, register=True, out=str(tmp_path / "o"))
    res = query.fn(cfg, request, plan_query(cfg, request, read_motion(tmp_path / "new_walk.bvh", unit="m")))
    assert res["query"]["clip"] == FILE_PREFIX + "new_walk.bvh"
    assert res["matches"] and {m["category"] for m in res["matches"]} == {"walk"}
    assert any(f.endswith("warps.csv") for f in res["files"])  # registered, the file's features included
    r = runner.invoke(app, ["search", str(app_store), "--query-file", str(tmp_path / "nope.bvh"), "--start", "1",
                            "--end", "2"])
    assert r.exit_code == 2 and "nope.bvh: no such file" in r.output
    r = runner.invoke(app, ["search", str(app_store), "--start", "1", "--end", "2"])
    assert r.exit_code == 2 and "exactly one of --clip" in r.output


#: subject 16 (one skeleton): three trials of each category indexed, one of each left out
INDEXED = {"jump": ("01", "02", "03"), "walk": ("15", "16", "17"), "run": ("35", "36", "37")}
LEFT_OUT = {"jump": "04", "walk": "18", "run": "38"}


@pytest.mark.slow
def test_cmu_trials_left_out_retrieve_their_category(prefect_harness, cmu_dir: Path, tmp_path: Path) -> None:
    from motionweb.flows.index import index_library

    src = cmu_dir / "asf_amc" / "16"
    need = ["16.asf"] + [f"16_{t}.amc" for ts in INDEXED.values() for t in ts] + [f"16_{t}.amc" for t in LEFT_OUT.values()]
    if not all((src / n).is_file() for n in need):
        pytest.skip(f"CMU subject 16 trials missing under {src}")
    corpus = tmp_path / "corpus" / "16"
    corpus.mkdir(parents=True)
    os.symlink(src / "16.asf", corpus / "16.asf")
    rows = ["path,category"]
    for cat, trials in INDEXED.items():
        for t in trials:
            os.symlink(src / f"16_{t}.amc", corpus / f"16_{t}.amc")
            rows.append(f"16/16_{t}.amc,{cat}")
    (tmp_path / "manifest.csv").write_text("\n".join(rows) + "\n")
    cfg_path = tmp_path / "config.yaml"
    cfg_path.write_text(yaml.safe_dump({"corpus": {"path": "corpus", "manifest": "manifest.csv"},
                                        "store": {"path": "store"}, "dask": {"processes": False}, "output": "out"}))
    cfg = load_config(cfg_path)
    index_library(cfg)
    for cat, t in LEFT_OUT.items():
        path = src / f"16_{t}.amc"
        motion = read_motion(path)
        mid = motion.duration / 2
        request = QueryRequest(clip=path.name, start=mid - 0.5, end=mid + 0.5, tiers=1, out=str(tmp_path / t))
        res = query.fn(cfg, request, plan_query(cfg, request, motion))
        assert res["matches"], f"16_{t} ({cat}) matched nothing"
        assert res["matches"][0]["category"] == cat, (t, [(m["clip"], m["category"]) for m in res["matches"][:5]])
