"""The query flow and `motionweb search` / `motionweb demo` end to end on the demo corpus.

One demo run (corpus, index, search with registration) per module, in Prefect's test harness.
"""

from __future__ import annotations

import json
import threading
from pathlib import Path

import pytest
from motionweb.flows import index as index_flow
from motionweb.flows.commands.cli import app
from motionweb.flows.commands.requests import QueryRequest
from motionweb.flows.config import load_config
from motionweb.flows.index import index_library
from motionweb.flows.query import query
from motionweb.store.bvh import read_bvh
from motionweb.store.generations import commit, current_id, load_generation
from motionweb.store.zarr_store import MotionStore
from typer.testing import CliRunner

runner = CliRunner()


@pytest.fixture(scope="module")
def demo(prefect_harness, tmp_path_factory):
    """(workdir, CLI output) of `motionweb demo` in a fresh folder."""
    mp = pytest.MonkeyPatch()
    for var, value in [("PREFECT_LOGGING_LEVEL", "WARNING"), ("DASK_LOGGING__DISTRIBUTED", "warning"),
                       ("PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS", "120")]:
        mp.setenv(var, value)  # what the CLI sets, restored after the module
    work = tmp_path_factory.mktemp("demo")
    r = runner.invoke(app, ["demo", "--workdir", str(work)])
    mp.undo()
    assert r.exit_code == 0, r.output
    return work, r.output


def test_demo_generates_indexes_searches_and_registers(demo) -> None:
    work, output = demo
    cfg = load_config(work / "config.yaml")
    assert cfg.corpus.path == str((work / "corpus").resolve())
    gen = load_generation(MotionStore(cfg.store.path, read_only=True))
    n_clips = len(list((work / "corpus").rglob("*.bvh")))
    assert len(gen.clips) == n_clips > 0 and not gen.broken
    assert f"clips {n_clips}" in output and f"computed {len(gen.webs)}, cached 0" in output
    res = json.loads((work / "out" / "matches.json").read_text())
    assert res["generation"] == gen.id and res["request"]["clip"] == cfg.demo.query_clip
    rows = res["matches"]
    assert len(rows) >= 2 and rows[0]["clip"] == cfg.demo.query_clip and rows[0]["distance"] == 0
    assert [r["distance"] for r in rows] == sorted(r["distance"] for r in rows)
    assert all(r["category"] == "walk" and r["cost"] <= res["epsilon"] for r in rows[1:])
    # registered examples share the query's length; warps.csv has a column per node
    q = rows[0]
    registered = sorted((work / "out" / "registered").glob("*.bvh"))
    assert len(registered) == len(rows)
    lengths = {read_bvh(p).n_frames for p in registered}
    assert lengths == {q["end_frame"] - q["start_frame"] + 1}
    header = (work / "out" / "warps.csv").read_text().splitlines()[0].split(",")
    assert len(header) == len(rows) + 1
    assert (work / "out" / "graph.png").stat().st_size > 0 and (work / "out" / "warps.png").stat().st_size > 0


def test_rerun_from_the_written_config_computes_nothing(demo) -> None:
    work, _ = demo
    r = runner.invoke(app, ["index", str(work / "config.yaml"), "--no-progress"])
    assert r.exit_code == 0, r.output
    assert "computed 0, cached" in r.output


def test_search_cli_table_export_and_tiers(demo, tmp_path: Path) -> None:
    work, _ = demo
    cfg_path = str(work / "config.yaml")
    base = ["search", cfg_path, "--clip", "walk_00", "--start", "1", "--end", "2.5", "--quantile", "0.8"]
    one = runner.invoke(app, [*base, "--tiers", "1", "--export", str(tmp_path / "exp"), "--out", str(tmp_path / "o1")])
    assert one.exit_code == 0, one.output
    rows = json.loads((tmp_path / "o1" / "matches.json").read_text())["matches"]
    assert {r["tier"] for r in rows} == {0, 1}
    exported = sorted((tmp_path / "exp").glob("*.bvh"))
    assert len(exported) == len(rows)
    for p, r in zip(exported, rows, strict=True):
        assert read_bvh(p).n_frames == r["end_frame"] - r["start_frame"] + 1
        assert Path(r["clip"]).stem in p.name
    for r in rows[1:]:
        assert r["clip"] in one.output
    many = runner.invoke(app, [*base, "--out", str(tmp_path / "o2")])
    assert many.exit_code == 0, many.output
    rows2 = json.loads((tmp_path / "o2" / "matches.json").read_text())["matches"]
    assert len(rows2) >= len(rows)


def test_search_cli_reads_back_the_graphs_it_packed(demo, tmp_path: Path, monkeypatch) -> None:
    """``motionweb search`` keeps the walk graphs it packs in the file cache (``app.graph_files_*``,
    here $MOTIONWEB_CACHE_DIR/graphs), and a later search reads them back and finds the same matches."""
    work, _ = demo
    monkeypatch.setenv("MOTIONWEB_CACHE_DIR", str(tmp_path / "cache"))
    base = ["search", str(work / "config.yaml"), "--clip", "walk_00", "--start", "1", "--end", "2.5",
            "--quantile", "0.8"]
    first = runner.invoke(app, [*base, "--out", str(tmp_path / "o1")])
    assert first.exit_code == 0, first.output
    kept = sorted((tmp_path / "cache" / "graphs").rglob("*.mwc"))
    assert kept
    stamps = [p.stat().st_mtime_ns for p in kept]
    second = runner.invoke(app, [*base, "--out", str(tmp_path / "o2")])
    assert second.exit_code == 0, second.output
    assert sorted((tmp_path / "cache" / "graphs").rglob("*.mwc")) == kept  # none packed again
    assert [p.stat().st_mtime_ns for p in kept] != stamps  # read: their use time refreshed
    got = [json.loads((tmp_path / o / "matches.json").read_text()) for o in ("o1", "o2")]
    assert got[0]["matches"] == got[1]["matches"] and got[0]["epsilon"] == got[1]["epsilon"]


@pytest.mark.parametrize(("args", "message"), [
    (["--clip", "nope", "--start", "0", "--end", "1", "--quantile", "0.5"], "unknown clip 'nope'"),
    (["--clip", "walk_00", "--start", "0", "--end", "99", "--quantile", "0.5"], "outside clip"),
    (["--clip", "walk_00", "--start", "0", "--end", "0.1", "--quantile", "0.5"], "shorter than the minimum chain"),
    (["--clip", "walk_00", "--start", "0", "--end", "1", "--threshold", "1", "--quantile", "0.5"],
     "at most one of threshold"),
    (["--clip", "walk_00", "--start", "0", "--end", "1", "--quantile", "1.5"], "quantile must lie in (0, 1)"),
])
def test_search_cli_bad_requests(demo, args: list[str], message: str) -> None:
    work, _ = demo
    r = runner.invoke(app, ["search", str(work / "config.yaml"), *args])
    assert r.exit_code == 2 and message in r.output and "Traceback" not in r.output


def test_search_of_a_store_never_indexed(tmp_path: Path) -> None:
    cfg = tmp_path / "c.yaml"
    cfg.write_text("store:\n  path: nothing-here\n")
    r = runner.invoke(app, ["search", str(cfg), "--clip", "a", "--start", "0", "--end", "1", "--threshold", "1"])
    assert r.exit_code == 2 and "never indexed" in r.output


def test_empty_result_is_reported(demo, tmp_path: Path) -> None:
    work, _ = demo
    r = runner.invoke(app, ["search", str(work / "config.yaml"), "--clip", "walk_00", "--start", "1", "--end", "2.5",
                            "--threshold", "0", "--out", str(tmp_path)])
    assert r.exit_code == 0 and "no matches" in r.output


def test_queries_are_served_while_an_index_run_writes(demo, monkeypatch) -> None:
    """A query reads the committed generation while a new one is written and not yet committed."""
    work, _ = demo
    cfg = load_config(work / "config.yaml")
    store = MotionStore(cfg.store.path, read_only=True)
    before = current_id(store)
    request = QueryRequest(clip=cfg.demo.query_clip, start=cfg.demo.query_start, end=cfg.demo.query_end,
                           quantile=cfg.demo.query_quantile, out=str(work / "q-during"))
    expected = query(cfg, request)["matches"]

    # change one clip, and hold the index run just before its commit
    clip = work / "corpus" / "walk" / "walk_01.bvh"
    clip.write_text(clip.read_text() + "\n")
    reached, release = threading.Event(), threading.Event()
    def held_commit(store, gen):
        reached.set()
        assert release.wait(120)
        return commit(store, gen)

    monkeypatch.setattr(index_flow, "commit", held_commit)
    result: dict = {}
    t = threading.Thread(target=lambda: result.update(index_library(cfg)))
    t.start()
    try:
        assert reached.wait(300), "the index run never reached its commit"
        during = query(cfg, request)
        assert during["generation"] == before and during["matches"] == expected
    finally:
        release.set()
        t.join(300)
    assert result["pairs_computed"] > 0 and current_id(store) == result["generation"] != before


def test_a_killed_index_run_leaves_the_last_generation_readable(demo, tmp_path: Path) -> None:
    """SIGKILL an index run (and its Prefect server and Dask workers) mid-way: the committed
    generation stays current and queryable, and the next run completes from what was written."""
    import os
    import signal
    import subprocess
    import sys
    import time

    work, _ = demo
    cfg = load_config(work / "config.yaml")
    store = MotionStore(cfg.store.path, read_only=True)
    before = current_id(store)
    clip = work / "corpus" / "run" / "run_00.bvh"
    clip.write_text(clip.read_text() + "\n")  # new content: its pairs must be recomputed
    root = Path(cfg.store.path)

    def objects() -> set[Path]:  # features are written before any web, webs well before the commit
        return {p for d in ("features", "webs") for p in (root / d).rglob("*") if p.is_file()}

    seen = objects()
    proc = subprocess.Popen([sys.executable, "-m", "motionweb.flows.commands.cli", "index", str(work / "config.yaml"), "--no-progress"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline and proc.poll() is None:
            if objects() - seen:
                break  # the run has started writing objects of the new generation
            time.sleep(0.02)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(60)
    assert current_id(store) == before
    res = query(cfg, QueryRequest(clip=cfg.demo.query_clip, start=cfg.demo.query_start, end=cfg.demo.query_end,
                                  quantile=cfg.demo.query_quantile, out=str(tmp_path)))
    assert res["generation"] == before and res["matches"]
    summary = index_library(cfg)
    assert summary["generation"] != before and current_id(store) == summary["generation"]
    assert summary["pairs_computed"] + summary["pairs_cached"] == summary["pairs"] and not summary["broken"]
