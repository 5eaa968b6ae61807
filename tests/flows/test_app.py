"""`motionweb app`: the JSON API (FastAPI's test client) on a tiny demo index, the CLI's
forwarding to a running service, generation switches, the security rules."""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from gltf_check import glb_world_positions
from motionweb.flows.app.api import MAX_BODY, create_app
from motionweb.flows.app.client import discovery_file, find_service
from motionweb.flows.app.engine import Engine, clip_id
from motionweb.flows.app.server import check_host
from motionweb.flows.commands.cli import app as cli
from motionweb.flows.config import load_config
from motionweb.flows.index import index_library
from motionweb.flows.query import match_rows, register_graph, segment_motion
from motionweb.store.bvh import parse_bvh
from motionweb.store.formats import read_motion
from motionweb.store.generations import load_generation
from motionweb.store.kinematics import forward_kinematics
from motionweb.store.webs import StoreWebs
from motionweb.store.zarr_store import MotionStore
from motionweb.tasks.features import joint_positions_m
from motionweb.tasks.matchgraph import Segment
from motionweb.tasks.ranking import default_epsilon, nearest_costs
from motionweb.tasks.search import MatchSearch, epsilon_from_quantile, search
from typer.testing import CliRunner

QUERY = {"clip": "walk_00", "start": 1.0, "end": 2.5, "quantile": 0.8}


@pytest.fixture(scope="module")
def cfg(app_store):
    return load_config(app_store)


@pytest.fixture(scope="module")
def client(cfg):
    return TestClient(create_app(Engine(cfg)))


def expected_search(cfg, clip: str, start: float, end: float, quantile: float, tiers: int | None = None):
    """What the query flow computes, from a fresh web source: (ε, rows)."""
    store = MotionStore(cfg.store.path, read_only=True)
    gen = load_generation(store)
    rec = next(c for c in gen.clips if Path(c["path"]).stem == clip)
    webs = StoreWebs.for_query(store, rec["path"], generation=gen)
    eps = epsilon_from_quantile(webs.all_webs(), quantile)
    scfg = cfg.search if tiers is None else cfg.search.model_copy(update={"max_tiers": tiers})
    rate = max(cfg.features.rates)
    graph = search(Segment(rec["path"], round(start * rate), round(end * rate)), eps, webs, scfg, cfg.matchweb)
    return eps, match_rows(graph, {c["path"]: c for c in gen.clips}), graph


def test_status_and_catalog_filters(client, cfg) -> None:
    gen = load_generation(MotionStore(cfg.store.path, read_only=True))
    s = client.get("/api/status").json()
    assert s["generation"] == gen.id and s["clips"] == len(gen.clips) == 6 and s["categories"] == {"walk": 3, "run": 3}
    all_rows = client.get("/api/catalog").json()
    assert [r["path"] for r in all_rows["clips"]] == sorted(c["path"] for c in gen.clips)
    assert all(r["id"] == clip_id(r["path"]) for r in all_rows["clips"])
    walk = client.get("/api/catalog", params={"category": "walk"}).json()["clips"]
    assert {r["path"] for r in walk} == {c["path"] for c in gen.clips if c["category"] == "walk"}
    assert [r["path"] for r in client.get("/api/catalog", params={"name": "RUN_01"}).json()["clips"]] == ["run/run_01.bvh"]
    durations = sorted(c["duration"] for c in gen.clips)
    mid = durations[2]
    short = client.get("/api/catalog", params={"max_s": mid}).json()
    assert short["total"] == sum(d <= mid for d in durations) and all(r["duration"] <= mid for r in short["clips"])
    page = client.get("/api/catalog", params={"offset": 2, "limit": 3}).json()
    assert page["total"] == 6 and [r["path"] for r in page["clips"]] == [r["path"] for r in all_rows["clips"][2:5]]


def test_clip_pose_is_forward_kinematics_in_metres(client, cfg, tmp_path: Path) -> None:
    rec = client.get("/api/catalog", params={"name": "walk_01"}).json()["clips"][0]
    pose = client.get(f"/api/clips/{rec['id']}/pose", params={"rate": 15}).json()
    m = read_motion(Path(cfg.corpus.path) / rec["path"], unit="m")
    want = joint_positions_m(segment_motion(m, np.arange(0, rec["duration"] * 15 + 1e-9), 15.0))
    got = np.array(pose["positions"]).reshape(pose["frames"], len(pose["parents"]), 3)
    assert pose["frames"] == len(want) == int(rec["duration"] * 15 + 1e-9) + 1
    np.testing.assert_allclose(got, want, atol=6e-4)  # rounded to the millimetre
    assert pose["parents"] == list(m.skeleton.parents) and pose["joints"] == list(m.skeleton.names)
    bvh = client.get(f"/api/clips/{rec['id']}/bvh")
    assert "attachment" in bvh.headers["content-disposition"]
    assert parse_bvh(bvh.text).n_frames == m.n_frames
    glb = client.get(f"/api/clips/{rec['id']}/glb")
    assert glb.headers["content-type"] == "model/gltf-binary" and ".glb" in glb.headers["content-disposition"]
    (tmp_path / "clip.glb").write_bytes(glb.content)
    got = glb_world_positions(tmp_path / "clip.glb")[0]
    np.testing.assert_allclose(got, forward_kinematics(m)[0] * m.metres(), atol=1e-4)


def test_search_equals_the_query_flows_search(client, cfg) -> None:
    for tiers in (None, 1, None):  # a cached search with other tiers, then back: same answers
        body = {**QUERY, **({"tiers": tiers} if tiers else {})}
        got = client.post("/api/search", json=body).json()
        eps, rows, _ = expected_search(cfg, **QUERY, tiers=tiers)
        assert got["epsilon"] == pytest.approx(eps, rel=1e-12)
        assert [{k: v for k, v in r.items() if k != "id"} for r in [got["query"], *got["matches"]]] == rows
        assert len(rows) > 2 and [r["distance"] for r in rows] == sorted(r["distance"] for r in rows)
    same_by_id = client.post("/api/search", json={**QUERY, "clip": clip_id("walk/walk_00.bvh")}).json()
    assert same_by_id["matches"] == got["matches"]
    thr = client.post("/api/search", json={"clip": "walk_00", "start": 1, "end": 2.5, "threshold": 0.0}).json()
    assert thr["matches"] == [] and thr["epsilon"] == 0.0
    # neither threshold nor quantile: the query flow's default rule, a multiple of the nearest match
    store = MotionStore(cfg.store.path, read_only=True)
    gen = load_generation(store)
    webs = StoreWebs.for_query(store, "walk/walk_00.bvh", generation=gen)
    near = nearest_costs(MatchSearch(webs, cfg.search, cfg.matchweb), Segment("walk/walk_00.bvh", 30, 75))
    got = client.post("/api/search", json={"clip": "walk_00", "start": 1, "end": 2.5}).json()
    assert got["epsilon"] == pytest.approx(default_epsilon(near, cfg.search.eps_nearest_ratio), rel=1e-12)
    assert len(got["matches"]) >= 1


def test_registration_and_registered_downloads(client, cfg) -> None:
    res = client.post("/api/search", json=QUERY).json()
    rid, n = res["result"], 1 + len(res["matches"])
    reg = client.get(f"/api/results/{rid}/registration").json()
    _, _, graph = expected_search(cfg, **QUERY)
    gen = load_generation(MotionStore(cfg.store.path, read_only=True))
    want = register_graph(MotionStore(cfg.store.path, read_only=True), gen, load_config_of(gen), graph,
                          {c["path"]: c for c in gen.clips})
    assert sorted(nd["rank"] for nd in reg["nodes"]) == list(range(n))
    for c, rank in enumerate(want.nodes):
        got = next(nd for nd in reg["nodes"] if nd["rank"] == rank)
        np.testing.assert_allclose(got["frames"], want.frames[:, c], atol=1e-3)
        f = np.array(got["frames"])
        assert np.all(np.diff(f) > 0) and f[0] == got["start"] and f[-1] == got["end"]
    q = res["query"]
    q_len = q["end_frame"] - q["start_frame"] + 1
    for rank in range(n):
        row = ([res["query"], *res["matches"]])[rank]
        seg = client.get(f"/api/results/{rid}/nodes/{rank}/bvh").text
        assert parse_bvh(seg).n_frames == row["end_frame"] - row["start_frame"] + 1
        regd = client.get(f"/api/results/{rid}/nodes/{rank}/bvh", params={"registered": True})
        assert parse_bvh(regd.text).n_frames == q_len and "_registered.bvh" in regd.headers["content-disposition"]
        glb = client.get(f"/api/results/{rid}/nodes/{rank}/glb", params={"registered": True})
        assert glb.content[:4] == b"glTF" and "_registered.glb" in glb.headers["content-disposition"]
        pose = client.get(f"/api/results/{rid}/nodes/{rank}/pose", params={"registered": True}).json()
        assert pose["frames"] == q_len and pose["rank"] == rank


def load_config_of(gen):
    from motionweb.flows.query import indexed_config

    return indexed_config(gen)


@pytest.mark.parametrize(("body", "status", "message"), [
    ({"clip": "nope", "start": 0, "end": 1, "quantile": 0.5}, 404, "unknown clip 'nope'"),
    ({"clip": "walk_00", "start": 0, "end": 99, "quantile": 0.5}, 400, "outside clip"),
    ({"clip": "walk_00", "start": 0, "end": 0.1, "quantile": 0.5}, 400, "shorter than the minimum chain"),
    ({"clip": "walk_00", "start": 0, "end": 1, "threshold": 1, "quantile": 0.5}, 400, "at most one of threshold"),
    ({"clip": "walk_00", "start": 0, "end": 1, "quantile": 1.5}, 400, "quantile must lie in (0, 1)"),
    ({"clip": "walk_00", "start": 0, "end": 1, "quantile": 0.5, "tiers": 99}, 400, "tiers must be ≤ 20"),
    ({"clip": "walk_00", "start": "x", "end": 1, "quantile": 0.5}, 400, "start: Input should be a valid number"),
    ({"clip": "walk_00", "start": 0, "end": 1, "quantile": 0.5, "path": "/etc"}, 400, "path: Extra inputs"),
    ({"clip": "walk_00", "start": 0, "end": 1, "quantile": 0.5, "search": {"max_tiers": "many"}}, 400,
     "search.max_tiers"),
    ({"clip": "x" * 301, "start": 0, "end": 1, "quantile": 0.5}, 400, "clip: String should have at most 300"),
])
def test_bad_searches_answer_json_with_the_clis_message(client, body, status, message) -> None:
    r = client.post("/api/search", json=body)
    assert r.status_code == status and message in r.json()["error"] and "Traceback" not in r.text


def test_unknown_ids_bad_bodies_and_bounds(client) -> None:
    assert client.get("/api/results/nope/registration").status_code == 404
    assert "unknown clip" in client.get("/api/clips/000000000000/pose").json()["error"]
    res = client.post("/api/search", json=QUERY).json()
    assert client.get(f"/api/results/{res['result']}/nodes/99/pose").status_code == 404
    r = client.post("/api/search", content=b"{not json", headers={"Content-Type": "application/json"})
    assert r.status_code == 400 and "error" in r.json()
    big = client.post("/api/search", content=b" " * (MAX_BODY + 1), headers={"Content-Type": "application/json"})
    assert big.status_code == 413
    assert client.get("/api/catalog", params={"name": "a" * 3000}).status_code == 414
    assert client.get("/api/clips/x/pose", params={"rate": 1000}).status_code == 400


def test_token_is_checked_on_every_request(cfg) -> None:
    token = "s3cret-token-0123456789"
    c = TestClient(create_app(Engine(cfg, warm=False), token))
    assert c.get("/api/status").status_code == 401
    assert c.get("/").status_code == 401 and c.get("/static/app.js").status_code == 401
    assert c.get("/api/status", headers={"Authorization": "Bearer wrong"}).status_code == 401
    assert c.get("/api/status", headers={"Authorization": f"Bearer {token}"}).status_code == 200
    page = c.get("/", params={"token": token})  # the page sets a cookie the browser sends after
    assert page.status_code == 200 and "motionweb" in page.text
    assert c.get("/static/app.js").status_code == 200 and c.get("/api/status").status_code == 200
    with pytest.raises(ValueError, match="give --token"):
        check_host("0.0.0.0", None)
    with pytest.raises(ValueError, match="at least 16"):
        check_host("0.0.0.0", "short")
    check_host("127.0.0.1", None)
    check_host("::1", None)


def test_page_and_its_files_are_served(client) -> None:
    page = client.get("/")
    assert page.status_code == 200 and '<canvas id="view"' in page.text and "/static/app.js" in page.text
    js = client.get("/static/app.js")
    assert js.status_code == 200 and "requestAnimationFrame" in js.text
    assert "http" not in page.text.replace("http-equiv", "")  # nothing outside the machine


def test_query_bundle_matches_a_local_search(client, cfg, tmp_path: Path) -> None:
    """The zip `motionweb search` gets from the service holds the files of a local run."""
    r = client.post("/api/query", json={**QUERY, "register": True, "export": "kept-as-text", "out": "o"})
    z = zipfile.ZipFile(io.BytesIO(r.content))
    res = json.loads(z.read("result.json"))
    names = set(z.namelist())
    assert {"out/matches.json", "out/graph.json", "out/graph.png", "out/warps.csv", "out/warps.png"} <= names
    n = 1 + len(res["matches"])
    assert len([x for x in names if x.startswith("export/")]) == n
    assert len([x for x in names if x.startswith("out/registered/")]) == n
    matches = json.loads(z.read("out/matches.json"))
    _, rows, _ = expected_search(cfg, **QUERY)
    assert matches["matches"] == rows and matches["request"]["export"] == "kept-as-text"


def test_cli_search_is_forwarded_to_a_running_service(running, app_store, tmp_path: Path) -> None:
    path = discovery_file(running.cfg.store.path)
    assert path.stat().st_mode & 0o777 == 0o600 and path.parent.stat().st_mode & 0o777 == 0o700
    assert find_service(running.cfg.store.path).url == running.url
    args = ["search", str(app_store), "--clip", "walk_00", "--start", "1", "--end", "2.5", "--quantile", "0.8",
            "--register", "--export", str(tmp_path / "exp"), "--out", str(tmp_path / "o")]
    r = CliRunner().invoke(cli, args)
    assert r.exit_code == 0, r.output
    assert f"by the service at {running.url}" in r.output
    rows = json.loads((tmp_path / "o" / "matches.json").read_text())["matches"]
    _, want, _ = expected_search(running.cfg, **QUERY)
    assert rows == want
    assert len(list((tmp_path / "exp").glob("*.bvh"))) == len(rows)
    assert len(list((tmp_path / "o" / "registered").glob("*.bvh"))) == len(rows)
    bad = CliRunner().invoke(cli, ["search", str(app_store), "--clip", "walk_00", "--start", "0", "--end", "99",
                                   "--quantile", "0.5"])
    assert bad.exit_code == 2 and "outside clip" in bad.output and "Traceback" not in bad.output


def test_forwarded_search_writes_the_bytes_of_a_local_run(running, app_store, tmp_path: Path, monkeypatch) -> None:
    """Every file a forwarded `motionweb search` writes (JSON, PNG, CSV, BVH) equals, byte for
    byte, what the same command writes with no service running."""
    args = ["search", str(app_store), "--clip", "walk_00", "--start", "1", "--end", "2.5", "--quantile", "0.8",
            "--tiers", "2", "--register", "--export", str(tmp_path / "exp"), "--out", str(tmp_path / "o")]
    r = CliRunner().invoke(cli, args)
    assert r.exit_code == 0 and "by the service" in r.output, r.output
    (tmp_path / "o").rename(tmp_path / "o-service")
    (tmp_path / "exp").rename(tmp_path / "exp-service")
    monkeypatch.setenv("MOTIONWEB_APP_DIR", str(tmp_path / "no-service"))
    r = CliRunner().invoke(cli, args)
    assert r.exit_code == 0 and "by the service" not in r.output, r.output

    def files(d: Path) -> dict[str, bytes]:
        return {p.relative_to(d).as_posix(): p.read_bytes() for p in sorted(d.rglob("*")) if p.is_file()}

    for mine, local in (("o-service", "o"), ("exp-service", "exp")):
        a, b = files(tmp_path / mine), files(tmp_path / local)
        assert a.keys() == b.keys() and len(a) >= 3
        assert [k for k in a if a[k] != b[k]] == []
    assert {"graph.png", "warps.png", "warps.csv", "matches.json", "graph.json"} <= set(files(tmp_path / "o"))


def test_a_forwarded_search_imports_nothing_heavy(running, app_store, tmp_path: Path) -> None:
    """The forwarding path of the CLI loads none of numpy, Prefect, matplotlib, Dask, Zarr."""
    code = ("import sys\nfrom motionweb.flows.commands.cli import app\ntry:\n    app(sys.argv[1:])\nexcept SystemExit as e:\n"
            "    assert not e.code, e.code\nheavy = ('numpy', 'prefect', 'matplotlib', 'dask', 'zarr', 'scipy', 'numba')\n"
            "print(sorted(m for m in heavy if m in sys.modules))")
    r = subprocess.run([sys.executable, "-c", code, "search", str(app_store), "--clip", "walk_00", "--start", "1",
                        "--end", "2.5", "--quantile", "0.8", "--out", str(tmp_path / "o")],
                       capture_output=True, text=True, timeout=300)
    assert "by the service" in r.stdout and r.stdout.strip().splitlines()[-1] == "[]", r.stdout + r.stderr
    assert (tmp_path / "o" / "graph.png").stat().st_size > 0


def test_a_stale_discovery_file_means_a_local_run(cfg, tmp_path: Path, monkeypatch) -> None:
    from motionweb.flows.app.client import write_discovery

    monkeypatch.setenv("MOTIONWEB_APP_DIR", str(tmp_path / "d"))
    write_discovery(cfg.store.path, {"url": "http://127.0.0.1:9", "token": None, "pid": 2 ** 22 + 12345})
    assert find_service(cfg.store.path) is None  # no such process
    write_discovery(cfg.store.path, {"url": "http://127.0.0.1:9", "token": None, "pid": os.getpid()})
    os.chmod(discovery_file(cfg.store.path), 0o644)
    assert find_service(cfg.store.path) is None  # readable by others: not trusted


def test_a_new_generation_is_switched_to_between_requests(cfg, tmp_path: Path) -> None:
    """Results keep their generation; after a commit new searches use the new one; a run that
    never commits changes nothing."""
    import shutil

    import yaml

    work = tmp_path / "w"
    shutil.copytree(Path(cfg.corpus.path), work / "corpus")
    shutil.copytree(Path(cfg.store.path), work / "store")
    cp = work / "config.yaml"
    cp.write_text(yaml.safe_dump({"corpus": {"path": "corpus", "length_unit": "m"}, "features": {"rates": [10.0, 30.0]},
                                  "store": {"path": "store"}, "dask": {"processes": False}}))
    c2 = load_config(cp)
    engine = Engine(c2, warm=False)
    c = TestClient(create_app(engine))
    before = c.post("/api/search", json=QUERY).json()
    clip = work / "corpus" / "walk" / "walk_01.bvh"
    clip.write_text(clip.read_text() + "\n")  # new content: a new generation
    summary = index_library(c2)
    assert summary["generation"] != before["generation"]
    engine.current(wait=True)
    after = c.post("/api/search", json=QUERY).json()
    assert after["generation"] == summary["generation"] and engine.switches == 2
    # the old result still registers and exports from its own generation
    reg = c.get(f"/api/results/{before['result']}/registration").json()
    assert len(reg["nodes"]) == 1 + len(before["matches"])
    assert c.get(f"/api/results/{before['result']}").json()["generation"] == before["generation"]


def test_answered_queries_are_recorded_as_prefect_flow_runs(prefect_harness, cfg) -> None:
    from motionweb.flows.app.recorder import PrefectServer, Recorder
    from prefect.client.orchestration import get_client
    from prefect.client.schemas.filters import FlowFilter, FlowFilterName
    from prefect.settings import PREFECT_API_URL

    server = PrefectServer()
    server.url = PREFECT_API_URL.value()
    server.ready.set()
    rec = Recorder(server)
    engine = Engine(cfg, on_query=rec.record, warm=False)
    res = engine.search(dict(QUERY))
    rec.queue.join()
    assert rec.recorded == 1 and rec.failed == rec.dropped == 0
    rec.close()
    with get_client(sync_client=True) as pc:
        runs = pc.read_flow_runs(flow_filter=FlowFilter(name=FlowFilterName(any_=["app-query"])))
        mine = [r for r in runs if r.parameters.get("outcome", {}).get("result") == res.id]
        assert len(mine) == 1 and mine[0].state.is_completed()
        assert mine[0].parameters["kind"] == "search" and mine[0].parameters["parameters"]["clip"] == "walk_00"



def test_a_query_that_matches_nothing_is_an_empty_result_with_a_message(client, cfg, tmp_path: Path) -> None:
    """Issue 22: a window whose rows no path crosses (found here in-process: a window ending on a
    clip's last frame) is answered with the query alone and a message, by the service and the
    query flow alike, not with an error."""
    from motionweb.flows.commands.requests import QueryRequest
    from motionweb.flows.query import query
    from motionweb.tasks.ranking import NO_MATCH

    store = MotionStore(cfg.store.path, read_only=True)
    gen = load_generation(store)
    found = None
    for rec in sorted(gen.clips, key=lambda c: c["path"]):
        webs = StoreWebs.for_query(store, rec["path"], generation=gen)
        ms = MatchSearch(webs, cfg.search, cfg.matchweb)
        g = ms.graph(rec["path"])
        for length in (10, 20, 30):
            for a in (g.n_frames - 1 - length, 0):
                if a >= 0 and not nearest_costs(ms, Segment(rec["path"], a, a + length)):
                    found = (rec["path"], a / g.rate, (a + length) / g.rate)
                    break
            if found:
                break
        if found:
            break
    assert found, "every window tried matches another clip: the fixture no longer has an empty query"
    clip, start, end = found
    got = client.post("/api/search", json={"clip": clip, "start": start, "end": end})
    assert got.status_code == 200, got.text
    body = got.json()
    assert body["matches"] == [] and body["epsilon"] is None and body["message"] == NO_MATCH
    res = query(cfg, QueryRequest(clip=clip, start=start, end=end, out=str(tmp_path)))
    assert res["matches"] == [] and res["epsilon"] is None and res["message"] == NO_MATCH


def _with_graph_files(cfg, folder) -> object:
    return cfg.model_copy(update={"app": cfg.app.model_copy(update={"graph_files_dir": str(folder)})})


def test_opening_a_generation_reads_no_web(cfg, tmp_path) -> None:
    """Issue 25: the service opens a generation whatever its size without reading its webs; a
    search then reads only the webs it reaches (their graphs kept in the worker's cache) and
    answers as the query flow does."""
    engine = Engine(_with_graph_files(cfg, tmp_path / "graphs"))  # warm: the worker opens every category's scope
    try:
        snap = engine.current()
        assert snap.warmed.wait(300)
        stats = engine.workers.cache_stats(wait=60)
        assert stats is not None and stats["webs_read"] == 0 and stats["entries"] == 0 and stats["bytes"] == 0
        eps, rows, _ = expected_search(cfg, **QUERY)
        res = engine.search({**{k: v for k, v in QUERY.items() if k != "quantile"}, "threshold": eps})
        assert res.rows == rows and len(rows) > 2
        stats = engine.workers.cache_stats(wait=60)
        walk_webs = sum(1 for w in snap.gen.webs if "walk/" in w["a"] and "walk/" in w["b"])
        # graphs are kept, not webs: a web is read for each of its two clips' graphs at most; the
        # graphs mapped from their files (app.graph_files_*), not in the memory cache
        assert 0 < stats["webs_read"] <= 2 * walk_webs and stats["entries"] == 0
        assert stats["graph_files"]["mapped"]["entries"] > 0 and stats["graph_files"]["writes"] > 0
        assert stats["max_bytes"] == int(cfg.app.cache_mb * 2**20) and stats["bytes"] <= stats["max_bytes"]
        assert engine.status()["cache"]["webs_read"] == stats["webs_read"]
    finally:
        engine.close()


def test_a_new_service_reads_the_graphs_packed_before_from_files(cfg, tmp_path) -> None:
    """Issue 25 part 5: the search workers keep each packed walk graph in files
    (``app.graph_files_gb``); a service started later (new workers, empty memory caches) reads
    them back instead of the webs and answers the same. With the files off, nothing is kept."""
    eps, rows, _ = expected_search(cfg, **QUERY)
    request = {**{k: v for k, v in QUERY.items() if k != "quantile"}, "threshold": eps}
    with_files = _with_graph_files(cfg, tmp_path / "graphs")
    for run in range(2):
        engine = Engine(with_files, warm=False)
        try:
            assert engine.search(request).rows == rows
            stats = engine.workers.cache_stats(wait=60)
            files = stats["graph_files"]
            assert files["folder"] == str(tmp_path / "graphs")
            if run == 0:
                assert stats["webs_read"] > 0 and files["writes"] > 0 and files["hits"] == 0
            else:
                assert stats["webs_read"] == 0 and files["hits"] > 0 and files["writes"] == 0
        finally:
            engine.close()
    assert list((tmp_path / "graphs").rglob("*.mwc"))
    off = cfg.model_copy(update={"app": cfg.app.model_copy(update={"graph_files_gb": 0.0,
                                                                   "graph_files_dir": str(tmp_path / "off")})})
    engine = Engine(off, warm=False)
    try:
        assert engine.search(request).rows == rows
        assert engine.workers.cache_stats(wait=60)["graph_files"] is None and not (tmp_path / "off").exists()
    finally:
        engine.close()


def test_a_cache_smaller_than_a_web_answers_the_same(cfg) -> None:
    """With ``app.cache_mb`` below one web every search reads its webs again and answers as the
    query flow does (quantile ε, tiers, clips of both categories). The graph files are off: with
    them, graphs are mapped from their files and the memory cache holds none."""
    tiny = cfg.model_copy(update={"app": cfg.app.model_copy(update={"cache_mb": 1e-3, "graph_files_gb": 0.0})})
    engine = Engine(tiny, warm=False)
    try:
        for clip, start, end in (("walk_00", 1.0, 2.5), ("run_01", 0.5, 1.5), ("walk_00", 1.0, 2.5)):
            for tiers in (None, 1):
                eps, rows, _ = expected_search(cfg, clip, start, end, 0.8, tiers)
                res = engine.search({"clip": clip, "start": start, "end": end, "quantile": 0.8, "tiers": tiers})
                assert res.epsilon == pytest.approx(eps, rel=1e-12) and res.rows == rows
        stats = engine.workers.cache_stats(wait=60)
        assert stats["max_bytes"] == int(1e-3 * 2**20) and stats["evictions"] > 0
        assert stats["bytes"] <= stats["max_bytes"] or stats["entries"] == 1
    finally:
        engine.close()


def test_the_primary_worker_opens_the_current_generation_at_start(cfg) -> None:
    """``SearchWorkers.start`` (the service's first step, beside its own manifest parse): the
    primary is up with the current generation open, which the warm-up and searches then use."""
    from motionweb.flows.app.worker import SearchWorkers, _State
    from motionweb.store.generations import load_generation

    gen = load_generation(MotionStore(cfg.store.path, read_only=True))
    state = _State(cfg.store.path)
    assert state.open_current() == gen.id
    opened = state.gens[gen.id][0]
    assert state.generation(gen.id)[0] is opened  # not parsed again
    workers = SearchWorkers(cfg.store.path, standby=False)
    try:
        workers.start()
        pid = workers.info()["pid"]
        assert pid is not None
        workers.prepare(gen.id, sorted({c["category"] for c in gen.clips}))
        assert workers.info()["pid"] == pid  # the same worker, warmed
    finally:
        workers.close()
    assert not workers.info()["pid"]
