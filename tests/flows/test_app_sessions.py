"""`motionweb app`'s retime sessions (MPS06, flows/app/sessions.py) through the JSON API: an edit
writes the bytes `motionweb retime` writes, a physics change prepares again and changes the
motion, bad inputs answer 400 JSON, the plan cache's bounds evict, a crash costs one request."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from motionweb.flows.app.api import create_app
from motionweb.flows.app.engine import Engine
from motionweb.flows.app.params import AppParams
from motionweb.flows.app.session_worker import CRASH_ENV, PlanCache, nbytes
from motionweb.flows.config import load_config
from motionweb.flows.retime import retime_flow

CLIP = "walk_00"


@pytest.fixture(scope="module")
def cfg(app_store):
    return load_config(app_store)


@pytest.fixture(scope="module")
def client(cfg):
    with TestClient(create_app(Engine(cfg, warm=False))) as c:
        yield c


def clip_file(cfg, stem: str) -> Path:
    return next(Path(cfg.corpus.path).rglob(f"{stem}.bvh"))


def open_session(client, **body) -> dict:
    r = client.post("/api/retime/sessions", json={"clip": CLIP, **body})
    assert r.status_code == 200, r.text
    return r.json()


def edit(client, sid: str, **body) -> dict:
    r = client.post(f"/api/retime/sessions/{sid}/edit", json=body)
    assert r.status_code == 200, r.text
    return r.json()


@pytest.mark.parametrize("physics", [{}, {"gravity": [1.5, -9.0, 0.0], "mass": {"LeftUpLeg": 2.0},
                                          "weight": {"RightUpLeg": 3.0}}])
def test_an_edit_writes_the_bytes_of_motionweb_retime(client, cfg, tmp_path: Path, physics) -> None:
    """The session's BVH and report equal the CLI's path (flows/retime.py) for the same clip,
    config, physics, duration and keytimes."""
    s = open_session(client, **physics)
    assert s["frames"] == len(s["original"]["positions"]) // (3 * len(s["joints"]))
    duration = round(0.8 * s["duration"], 3)
    keytimes = [[1.0, 0.85]]
    ans = edit(client, s["session"], duration=duration, keytimes=keytimes)
    out = tmp_path / "cli.bvh"
    rep = retime_flow.fn(str(clip_file(cfg, CLIP)), cfg, str(out), duration=duration,
                         keytimes=[tuple(k) for k in keytimes], gravity=physics.get("gravity"),
                         mass=physics.get("mass"), weight_factors=physics.get("weight"))
    bvh = client.get(f"/api/retime/sessions/{s['session']}/bvh")
    assert bvh.status_code == 200 and "attachment" in bvh.headers["content-disposition"]
    assert bvh.content == out.read_bytes()
    mine = client.get(f"/api/retime/sessions/{s['session']}/report").json()
    cli = json.loads(out.with_suffix(".json").read_text())
    for key in ("frames", "flights", "contacts", "phase_seconds", "reachable", "infeasible_output_frames",
                "gravity", "mass_factors", "weight_factors", "timing", "objective"):
        assert mine[key] == cli[key], key
    assert rep["frames_out"] == len(ans["t"]) == ans["pose"]["frames"]
    # the plots' data: p(t) and linear timing, polygons, torques against limits, contacts, reachability
    assert ans["p"] == [f["source_time"] for f in cli["frames"]]
    assert ans["linear"][-1] == pytest.approx(s["duration"])
    assert len(s["polygons"]) == s["frames"] and max(ans["source_frame"]) < s["frames"]
    assert len(ans["torques"]["max_ratio"]) == len(ans["t"]) and ans["torques"]["joints"]
    assert ans["shortest_feasible_duration"] == cli["shortest_feasible_duration"]
    assert set(ans["contacts"]) == set(cli["contacts"])


def test_a_physics_change_prepares_again_and_changes_the_motion(client) -> None:
    a = open_session(client)
    b = open_session(client, gravity=[0.0, -4.0, 0.0])
    c = open_session(client)  # the same physics as a: its plan is kept
    assert b["plans"] == a["plans"] + 1 and c["plans"] == b["plans"]
    assert b["reused_dynamics"] and c["reused_dynamics"]  # the clip's path dynamics and contacts kept
    assert b["polygons"] != a["polygons"] and c["polygons"] == a["polygons"]
    ea, eb = (edit(client, x["session"], duration=round(0.7 * x["duration"], 3)) for x in (a, b))
    assert ea["pose"]["positions"] != eb["pose"]["positions"] and ea["p"] != eb["p"]
    ta, tb = (client.get(f"/api/retime/sessions/{x['session']}/bvh").content for x in (a, b))
    assert ta != tb
    assert edit(client, c["session"], duration=round(0.7 * c["duration"], 3))["p"] == ea["p"]
    # a timing edit changes the motion that plays
    e2 = edit(client, a["session"], duration=round(0.7 * a["duration"], 3), keytimes=[[1.0, 1.2]])
    assert e2["pose"]["positions"] != ea["pose"]["positions"]


@pytest.mark.parametrize(("path", "body", "status", "message"), [
    ("/api/retime/sessions", {"clip": "no_such_clip"}, 404, "no_such_clip"),
    ("/api/retime/sessions", {"clip": CLIP, "gravity": [0, -1000, 0]}, 400, "gravity"),
    ("/api/retime/sessions", {"clip": CLIP, "gravity": [0, -9.8]}, 400, "gravity"),
    ("/api/retime/sessions", {"clip": CLIP, "mass": {"NoSuchJoint": 2.0}}, 400, "NoSuchJoint"),
    ("/api/retime/sessions", {"clip": CLIP, "weight": {"LeftUpLeg": -1}}, 400, "factor"),
    ("/api/retime/sessions", {"clip": CLIP, "path": "/etc/passwd"}, 400, "path"),
    ("/api/retime/sessions/nosuchsession/edit", {"duration": 2.0}, 404, "nosuchsession"),
])
def test_bad_session_requests_answer_json_errors(client, path, body, status, message) -> None:
    r = client.post(path, json=body)
    assert r.status_code == status, r.text
    assert message in r.json()["error"] and "Traceback" not in r.text


@pytest.mark.parametrize(("body", "message"), [
    ({"duration": -1.0}, "duration"),
    ({"duration": 1e9}, "duration"),
    ({"duration": 3.0, "keytimes": [[99.0, 1.0]]}, "keytime"),
    ({"duration": 3.0, "keytimes": [[1.0, 2.0], [0.5, 2.5]]}, "increase"),
    ({"duration": 3.0, "keytimes": [[1.0]]}, "keytimes"),
    ({"duration": "soon"}, "duration"),
])
def test_bad_edits_answer_400_with_the_reason(client, body, message) -> None:
    s = open_session(client)
    r = client.post(f"/api/retime/sessions/{s['session']}/edit", json=body)
    assert r.status_code == 400, r.text
    assert message in r.json()["error"]
    assert client.get(f"/api/retime/sessions/{s['session']}/bvh").status_code == 404  # no timing yet


def test_the_plan_cache_evicts_by_count_and_bytes(cfg) -> None:
    cache = PlanCache(max_plans=2, max_bytes=10_000)
    for k in "abc":
        cache.put(k, {"x": np.zeros(100)})
    assert list(cache.items) == ["b", "c"] and cache.evicted == 1
    cache.get("b")
    cache.put("d", {"x": np.zeros(1000)})  # 8000 bytes: c (least recently used) goes
    assert list(cache.items) == ["b", "d"]
    cache.put("e", {"x": np.zeros(1100)})  # 8800 bytes: b and d go, e stays alone
    assert list(cache.items) == ["e"] and cache.total == 8800 and cache.evicted == 4
    kept = PlanCache(max_plans=1, max_bytes=10_000)  # a clip's dynamics live as long as a plan of it
    kept.put("a1", {}, "clip-a", "dynamics-a")
    kept.put("a2", {}, "clip-a", None)
    assert kept.physics == {"clip-a": "dynamics-a"}
    kept.put("b1", {}, "clip-b", "dynamics-b")
    assert kept.physics == {"clip-b": "dynamics-b"}
    dyn = np.zeros(500)  # two physics of one clip share its path dynamics: counted once
    two = PlanCache(max_plans=4, max_bytes=10_000)
    two.put("p1", {"terms": dyn, "poly": np.zeros(10)}, "clip", {"terms": dyn})
    two.put("p2", {"terms": dyn, "poly": np.zeros(10)}, "clip", {"terms": dyn})
    assert two.total == 4000 + 160
    shared = np.zeros(10)
    assert nbytes({"a": shared, "b": [shared, shared[2:]]}) == 80
    # the service: one plan kept; an evicted session is prepared again on its next edit
    with TestClient(create_app(Engine(cfg.model_copy(update={"app": AppParams(session_plans=1)}), warm=False))) as c:
        a, b = open_session(c), open_session(c, clip="walk_01")
        assert b["plans"] == 1
        ea = edit(c, a["session"], duration=3.0)
        assert ea["duration_out"] == pytest.approx(3.0)
        info = c.app.app.state.retime_sessions.worker_info()
        assert info["plans"] == 1 and info["evicted"] == 2


def test_a_crash_in_a_session_costs_only_its_request(cfg, monkeypatch) -> None:
    monkeypatch.setenv(CRASH_ENV, "walk_01")
    with TestClient(create_app(Engine(cfg, warm=False))) as c:
        a = open_session(c)
        r = c.post("/api/retime/sessions", json={"clip": "walk_01"})
        assert r.status_code == 500 and "crashed its worker process (SIGSEGV)" in r.json()["error"]
        assert r.json()["query"]["clip"].endswith("walk_01.bvh")
        # the next request gets a fresh worker, which prepares a's plan again
        assert edit(c, a["session"], duration=3.0)["duration_out"] == pytest.approx(3.0)
        assert c.app.app.state.retime_sessions.crashes == 1


# ---------------------------------------------------------------- warp sessions (HDP07)
@pytest.mark.parametrize(("reference", "fast"), [(None, False), ("walk_01", True)])
def test_a_warp_edit_writes_the_bytes_of_motionweb_warp(client, cfg, tmp_path: Path, reference, fast) -> None:
    """The warp session's BVH equals `motionweb warp`'s (flows/warp.py) for the same clip,
    reference, duration and keytimes; a second edit reuses the local scores (HDP07 §3.2)."""
    from motionweb.flows.warp import WarpRequest, run_warp

    r = client.post("/api/warp/sessions", json={"clip": CLIP, "reference": reference})
    assert r.status_code == 200, r.text
    s = r.json()
    for duration, keytimes in ((round(0.7 * s["duration"], 3), [[1.0, 0.6]]), (round(0.8 * s["duration"], 3), [])):
        e = client.post(f"/api/warp/sessions/{s['session']}/edit",
                        json={"duration": duration, "keytimes": keytimes, "fast": fast})
        assert e.status_code == 200, e.text
        ans = e.json()
        out = tmp_path / f"cli-{duration}.bvh"
        summary = run_warp(cfg, WarpRequest(input=str(clip_file(cfg, CLIP)), out=str(out),
                                            reference=str(clip_file(cfg, reference)) if reference else None,
                                            duration=duration, keytimes=tuple(tuple(k) for k in keytimes), fast=fast))
        bvh = client.get(f"/api/warp/sessions/{s['session']}/bvh")
        assert bvh.content == out.read_bytes()
        assert ans["output_frames"] == summary["output_frames"] == len(ans["times_s"]) == ans["pose"]["frames"]
        assert ans["flights"] == summary["flights"] and ans["cost"] == pytest.approx(summary["cost"])
        assert len(ans["linear_s"]) == len(ans["times_s"])
    assert "objective" not in ans["timings"]  # the second edit: scores reused


def test_bad_warp_requests_answer_json_errors(client) -> None:
    assert client.post("/api/warp/sessions", json={"clip": CLIP, "reference": "nope"}).status_code == 404
    s = client.post("/api/warp/sessions", json={"clip": CLIP}).json()
    for body, message in (({"duration": -2}, "duration"), ({"duration": 2.0, "keytimes": [[50.0, 1.0]]}, "keytime"),
                          ({}, "duration")):
        r = client.post(f"/api/warp/sessions/{s['session']}/edit", json=body)
        assert r.status_code == 400 and message in r.json()["error"].lower(), r.text


# ---------------------------------------------------------------- uploads (clips of the user's own)
def upload(client, name: str, **body):
    return client.post("/api/uploads", json={"name": name, **body})


def test_an_uploaded_clip_retimes_and_warps_as_the_indexed_one(client, cfg) -> None:
    """walk_00 uploaded under another name (a label, never a path) gives the indexed clip's bytes."""
    text = clip_file(cfg, CLIP).read_text()
    before = sorted(p.name for p in Path(cfg.corpus.path).rglob("*"))
    r = upload(client, "../../etc/My walk.bvh", bvh=text, unit="m")
    assert r.status_code == 200, r.text
    up = r.json()
    assert up["id"].startswith("up-") and up["name"] == "My_walk" and up["path"] == "upload/My_walk.bvh"
    assert upload(client, "again", bvh=text, unit="m").json()["id"] == up["id"]  # content-addressed
    assert client.get(f"/api/uploads/{up['id']}").json()["frames"] == up["frames"]
    body = {"duration": 3.0, "keytimes": [[1.0, 0.9]]}
    bvhs = []
    for clip in (CLIP, up["id"]):
        s = open_session(client, clip=clip)
        edit(client, s["session"], **body)
        bvhs.append(client.get(f"/api/retime/sessions/{s['session']}/bvh").content)
    assert bvhs[0] == bvhs[1]
    w = client.post("/api/warp/sessions", json={"clip": up["id"], "reference": CLIP}).json()
    e = client.post(f"/api/warp/sessions/{w['session']}/edit", json={"duration": 2.5})
    assert e.status_code == 200 and e.json()["output_frames"] == round(2.5 * up["fps"]) + 1
    assert sorted(p.name for p in Path(cfg.corpus.path).rglob("*")) == before  # nothing written


def test_an_asf_amc_pair_uploads(client) -> None:
    from fixtures import CHAIN_AMC, CHAIN_ASF

    r = upload(client, "chain", asf=CHAIN_ASF, amc=CHAIN_AMC, fps=30)
    assert r.status_code == 200, r.text
    assert r.json()["fps"] == 30 and r.json()["path"] == "upload/chain.amc"


@pytest.mark.parametrize(("body", "status", "message"), [
    ({"bvh": "HIERARCHY\nROOT Hips\n{"}, 400, "chain.bvh"),  # the reader's message names the upload
    ({"bvh": "nothing here", "unit": "m"}, 400, "HIERARCHY"),
    ({"bvh": "x", "asf": "y", "amc": "z"}, 400, "either bvh"),
    ({"asf": "y"}, 400, "either bvh"),
    ({"bvh": "x", "unit": "furlong"}, 400, "unit"),
    ({"bvh": "x", "path": "/etc/passwd"}, 400, "path"),
])
def test_bad_uploads_answer_400_json(client, body, status, message) -> None:
    r = upload(client, "chain", **body)
    assert r.status_code == status, r.text
    assert message in r.json()["error"] and "Traceback" not in r.text


def test_uploads_are_bounded_and_expire(cfg) -> None:
    text = clip_file(cfg, CLIP).read_text()
    small = cfg.model_copy(update={"app": AppParams(upload_bytes=64 * 1024, uploads=1, upload_ttl_s=1e-3)})
    with TestClient(create_app(Engine(small, warm=False))) as c:
        r = upload(c, "big", bvh=text + " " * 70_000, unit="m")
        assert r.status_code == 413 and "larger than 65536" in r.json()["error"]
        assert c.post("/api/search", json={"clip": "x" * 70_000}).status_code == 413  # other routes: 64 KiB
        cut = text.split("MOTION")[0] + "MOTION\nFrames: 2\nFrame Time: 0.0333\n" + "\n".join(
            text.split("Frame Time:")[1].split("\n")[1:3]) + "\n"
        up = upload(c, "two", bvh=cut, unit="m")
        assert up.status_code == 200, up.text
        import time

        time.sleep(0.01)
        assert c.get(f"/api/uploads/{up.json()['id']}").status_code == 404  # expired


def test_the_upload_route_takes_the_reader_fuzz_mutants(client, cfg) -> None:
    """Mutants of a BVH (tests/store/test_reader_fuzz.py's mutations) through the route: each is a
    clip (200) or a JSON error naming the problem (400), never a crash or a traceback."""
    import importlib.util
    import random

    spec = importlib.util.spec_from_file_location("reader_fuzz", Path(__file__).parents[1] / "store" / "test_reader_fuzz.py")
    fuzz = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(fuzz)
    text = clip_file(cfg, CLIP).read_text()
    rng = random.Random(24)
    seen = {200: 0, 400: 0}
    for _ in range(60):
        r = upload(client, "mutant", bvh=fuzz.mutate(text, rng), unit="m")
        assert r.status_code in (200, 400), r.text
        assert "Traceback" not in r.text and (r.status_code == 200 or r.json()["error"])
        seen[r.status_code] += 1
    assert seen[400] > 0


def test_the_session_worker_ends_with_the_service(cfg, tmp_path: Path, monkeypatch) -> None:
    import threading
    import time
    import urllib.request

    import psutil
    from motionweb.flows.app.server import Service

    monkeypatch.setenv("MOTIONWEB_APP_DIR", str(tmp_path))
    svc = Service(cfg, port=0, record=False, warm=False)
    t = threading.Thread(target=svc.run, daemon=True)
    t.start()
    while not svc.server.started:
        time.sleep(0.05)

    def call(path: str, body: dict | None = None) -> dict:
        req = urllib.request.Request(svc.url + path, data=None if body is None else json.dumps(body).encode(),
                                     headers={"Content-Type": "application/json"})
        with urllib.request.urlopen(req, timeout=120) as r:
            return json.loads(r.read())

    call("/api/retime/sessions", {"clip": CLIP})
    pid = call("/api/retime/status")["pid"]
    assert pid is not None and psutil.pid_exists(pid)
    svc.stop()
    t.join(30)
    assert not psutil.pid_exists(pid) or psutil.Process(pid).status() == psutil.STATUS_ZOMBIE


def test_sessions_and_uploads_need_the_token(cfg) -> None:
    token = "s3cret-token-0123456789"
    with TestClient(create_app(Engine(cfg, warm=False), token=token)) as c:
        for path, body in (("/api/retime/sessions", {"clip": CLIP}), ("/api/warp/sessions", {"clip": CLIP}),
                           ("/api/uploads", {"name": "x", "bvh": "x"}), ("/api/retime/sessions/abc/edit", {})):
            r = c.post(path, json=body)
            assert r.status_code == 401 and "token" in r.json()["error"]
        r = c.post("/api/retime/sessions", json={"clip": CLIP}, headers={"Authorization": f"Bearer {token}"})
        assert r.status_code == 200, r.text
