"""On-demand commands run in the CLI's process without Prefect when no server is there, write the
bytes the Prefect flow run writes, and are recorded as flow runs after the answer when a server is
there (issue 23, flows/runtime/lazy_prefect.py, flows/runtime/history.py); ``index`` with nothing to do answers
without Prefect, and still leaves a damaged store to the flow (flows/index.py unchanged_summary)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from motionweb.flows.config import load_config

#: runs the CLI in a new process with no server configured, then says whether Prefect was imported
NO_PREFECT = """
import sys
from motionweb.flows.commands.cli import app
try:
    app(sys.argv[1:], standalone_mode=False)
finally:
    print("PREFECT_IMPORTED" if "prefect" in sys.modules else "NO_PREFECT")
"""


def cold_env(tmp_path: Path) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("PREFECT_API")}
    env.update(PREFECT_HOME=str(tmp_path / "prefect"), MOTIONWEB_APP_DIR=str(tmp_path / "disc"))
    return env


@pytest.fixture(scope="module")
def local_cfg(app_store: Path, tmp_path_factory) -> Path:
    """``app_store``'s config with an output folder of this module's own."""
    tmp = tmp_path_factory.mktemp("local")
    data = yaml.safe_load(app_store.read_text())
    data.update(store={"path": str(app_store.parent / "store")}, output=str(tmp / "out"))
    data["corpus"]["path"] = str(app_store.parent / "corpus")
    (tmp / "config.yaml").write_text(yaml.safe_dump(data))
    return tmp / "config.yaml"


def test_warp_and_search_run_without_prefect(local_cfg: Path, tmp_path: Path) -> None:
    clip = str(Path(load_config(local_cfg).corpus.path) / "walk" / "walk_00.bvh")
    for args in (["warp", clip, "--duration", "2.0", "--out", str(tmp_path / "w.bvh"), "--config", str(local_cfg)],
                 ["search", str(local_cfg), "--clip", "walk_00", "--start", "1", "--end", "2.5",
                  "--out", str(tmp_path / "s")]):
        r = subprocess.run([sys.executable, "-c", NO_PREFECT, *args], env=cold_env(tmp_path), capture_output=True,
                           text=True, timeout=600, check=False)
        assert r.returncode == 0, r.stderr
        assert r.stdout.rstrip().endswith("NO_PREFECT"), (args[0], r.stdout, r.stderr)
    assert (tmp_path / "w.bvh").is_file() and (tmp_path / "s" / "matches.json").is_file()


def test_the_flow_run_and_the_plain_run_write_the_same_bytes(prefect_harness, local_cfg: Path,
                                                           tmp_path: Path) -> None:
    from motionweb.flows.commands.requests import QueryRequest, WarpRequest
    from motionweb.flows.query import query
    from motionweb.flows.retime import retime_flow
    from motionweb.flows.warp import warp

    cfg = load_config(local_cfg)
    clip = str(Path(cfg.corpus.path) / "walk" / "walk_00.bvh")
    out = tmp_path / "o"
    written = {}
    for how in ("flow", "plain"):
        shutil.rmtree(out, ignore_errors=True)
        req = WarpRequest(input=clip, out=str(out / "w.bvh"), duration=2.0, plot=str(out / "w.png"))
        (warp if how == "flow" else warp.fn)(cfg, req)
        (retime_flow if how == "flow" else retime_flow.fn)(clip, cfg, str(out / "r.bvh"), duration=1.5)
        q = QueryRequest(clip="walk_00", start=1.0, end=2.5, register=True, out=str(out / "q"))
        (query if how == "flow" else query.fn)(cfg, q)
        written[how] = {p.relative_to(out).as_posix(): p.read_bytes() for p in sorted(out.rglob("*"))
                        if p.is_file() and p.name != "r.json"}  # r.json holds wall times
    assert sorted(written["flow"]) == sorted(written["plain"])
    assert "q/registered" in {str(Path(k).parent) for k in written["flow"]}
    for name, data in written["flow"].items():
        assert written["plain"][name] == data, name


def test_a_run_is_recorded_after_the_answer_when_a_server_is_there(prefect_harness, local_cfg: Path,
                                                                  tmp_path: Path) -> None:
    import asyncio

    from motionweb.flows.commands.cli import app
    from prefect.client.orchestration import get_client
    from prefect.client.schemas.filters import FlowFilter, FlowFilterName
    from typer.testing import CliRunner

    r = CliRunner().invoke(app, ["search", str(local_cfg), "--clip", "walk_00", "--start", "1", "--end", "2",
                                 "--out", str(tmp_path / "s")])
    assert r.exit_code == 0, r.output

    async def runs() -> list:
        async with get_client() as client:
            return await client.read_flow_runs(flow_filter=FlowFilter(name=FlowFilterName(any_=["query"])))

    found = [fr for fr in asyncio.run(runs()) if fr.parameters.get("kind") == "query"
             and fr.parameters["parameters"]["request"]["out"] == str(tmp_path / "s")]
    assert len(found) == 1 and found[0].state.is_completed()
    assert found[0].parameters["outcome"]["out"] == str(tmp_path / "s")


def test_index_with_nothing_to_do_answers_without_prefect_unless_the_store_is_damaged(
        prefect_harness, app_store: Path, tmp_path: Path) -> None:
    from motionweb.flows.index import index_library, unchanged_summary

    data = yaml.safe_load(app_store.read_text())
    shutil.copytree(app_store.parent / "store", tmp_path / "store")
    data.update(store={"path": str(tmp_path / "store")}, output=str(tmp_path / "out"))
    data["corpus"]["path"] = str(app_store.parent / "corpus")
    (tmp_path / "c.yaml").write_text(yaml.safe_dump(data))
    cfg = load_config(tmp_path / "c.yaml")
    assert unchanged_summary(cfg) is None  # another store path: a generation of its own to commit
    index_library(cfg)  # (the flow: its objects are reused)
    s = unchanged_summary(cfg)
    assert s is not None and s["pairs_computed"] == 0 and s["features_computed"] == 0 and s["pairs"] > 0
    r = subprocess.run([sys.executable, "-c", NO_PREFECT, "index", str(tmp_path / "c.yaml"), "--no-progress"],
                       env=cold_env(tmp_path), capture_output=True, text=True, timeout=600, check=False)
    assert r.returncode == 0 and f"generation {s['generation']}" in r.stdout, r.stdout + r.stderr
    assert "computed 0" in r.stdout
    # a damaged object or a damaged pointer: the flow's to repair
    web = next(p for p in sorted((tmp_path / "store").rglob("*")) if p.is_file() and "/webs/" in p.as_posix()
               and "/c/" in p.as_posix() and p.stat().st_size > 0)
    saved = web.read_bytes()
    web.write_bytes(b"x" + saved[1:])
    assert unchanged_summary(cfg) is None
    web.write_bytes(saved)
    assert unchanged_summary(cfg) is not None
    (tmp_path / "store" / "current").write_text("garbage")
    assert unchanged_summary(cfg) is None


def test_an_index_run_with_only_a_commit_to_make_reads_the_webs_once(prefect_harness, app_store: Path,
                                                                    tmp_path: Path, monkeypatch) -> None:
    """A run whose config changed (or one web damaged) but nothing else: the no-Prefect check
    verifies every reused web, finds a commit (or a web) to make and hands its answers to the flow,
    whose plan does not read them again; the damaged web is still recomputed."""
    from motionweb.flows import index as idx
    from motionweb.flows.commands import cli
    from motionweb.flows.commands.cli import run_index
    from motionweb.store.zarr_store import MotionStore

    monkeypatch.setattr(cli, "server_url", lambda: None)  # no server to record to: the check runs first

    data = yaml.safe_load(app_store.read_text())
    shutil.copytree(app_store.parent / "store", tmp_path / "store")
    data.update(store={"path": str(tmp_path / "store")}, output=str(tmp_path / "out"))
    data["corpus"]["path"] = str(app_store.parent / "corpus")
    (tmp_path / "c.yaml").write_text(yaml.safe_dump(data))
    passes: list[int] = []
    real = MotionStore.verify_webs

    def counted(self, keys, *args, **kwargs):
        keys = list(keys)
        passes.append(len(keys))
        return real(self, keys, *args, **kwargs)

    monkeypatch.setattr(MotionStore, "verify_webs", counted)
    first = run_index(load_config(tmp_path / "c.yaml"), False, ahead=[])  # another store path: a commit
    assert first["pairs_computed"] == 0 and len(passes) == 1 and passes[0] == first["pairs"]
    web = next(p for p in sorted((tmp_path / "store").rglob("*")) if p.is_file() and "/webs/" in p.as_posix()
               and "/c/" in p.as_posix() and p.stat().st_size > 0)
    web.write_bytes(b"x" + web.read_bytes()[1:])
    passes.clear()
    second = run_index(load_config(tmp_path / "c.yaml"), False, ahead=[])
    assert len(passes) == 1 and second["pairs_computed"] >= 1  # the web recomputed (same bytes: same generation)
    assert idx.VERIFIED is None  # nothing left behind for a later run of this process
    passes.clear()
    third = run_index(load_config(tmp_path / "c.yaml"), False, ahead=[])  # repaired: nothing to do
    assert third["generation"] == first["generation"] and third["pairs_computed"] == 0 and len(passes) == 1


@pytest.mark.parametrize(("module", "absent"), [
    ("motionweb.flows.commands.cli", ("numba", "scipy", "zarr", "prefect", "distributed", "pinocchio", "matplotlib")),
    ("motionweb.flows.config", ("numba", "scipy", "zarr", "prefect", "distributed", "pinocchio")),
    ("motionweb.flows.index", ("numba", "prefect", "distributed", "pinocchio")),
    ("motionweb.flows.commands.requests", ("numpy", "numba", "zarr", "prefect")),
])
def test_light_modules_stay_light(module, absent) -> None:
    """What every command imports before its work (the CLI, the run config with every stage's
    parameter model, the index's plan, the request models) loads none of the heavy libraries the
    work may need (issue 23: a command costs about its work)."""
    import subprocess
    import sys

    code = f"import sys, {module}; print(','.join(m for m in {absent!r} if m in sys.modules))"
    got = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert got == "", f"importing {module} loads {got}"
