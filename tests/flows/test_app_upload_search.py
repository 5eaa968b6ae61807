"""`motionweb app`: an uploaded clip as a search query (issue 24; KG04 §3.3). Its features and its
webs against the indexed clips are built on demand by the search worker with ``search
--query-file``'s code path (``flows/query.prepare_file_query``) and kept with the upload (the
bounded upload cache); the matches are those of the CLI, and an upload of an indexed file is that
clip. Bad ids and windows answer JSON errors naming the field, and the service goes on."""

from __future__ import annotations

from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from motionweb.flows.app.api import create_app
from motionweb.flows.app.engine import Engine
from motionweb.flows.commands.requests import QueryRequest
from motionweb.flows.config import load_config
from motionweb.flows.query import plan_query, query
from motionweb.store.formats import read_motion

WINDOW = {"start": 1.0, "end": 2.5, "quantile": 0.8}
KEYS = ("clip", "category", "start_frame", "end_frame", "tier")


@pytest.fixture(scope="module")
def cfg(app_store):
    return load_config(app_store)


@pytest.fixture(scope="module")
def client(cfg):
    with TestClient(create_app(Engine(cfg))) as c:
        yield c


def upload(client, name: str, text: str) -> dict:
    r = client.post("/api/uploads", json={"name": name, "bvh": text, "unit": "m"})
    assert r.status_code == 200, r.text
    return r.json()


def search(client, **body) -> dict:
    r = client.post("/api/search", json={**WINDOW, **body})
    assert r.status_code == 200, r.text
    return r.json()


def rows(matches: list[dict], query: str = "") -> list[tuple]:
    """The matches' clips (``query``: the query clip's name, as "QUERY"), segments, tiers, costs."""
    return [("QUERY" if m["clip"] == query else m["clip"], *(m[k] for k in KEYS[1:]), round(m["cost"], 9),
             round(m["distance"], 9)) for m in matches]


def test_an_indexed_clip_uploaded_under_another_name_finds_the_indexed_querys_matches(client, cfg) -> None:
    text = (Path(cfg.corpus.path) / "walk" / "walk_00.bvh").read_text()
    up = upload(client, "renamed walk.bvh", text)
    indexed = search(client, clip="walk_00")
    mine = search(client, clip=up["id"])
    assert indexed["matches"] and rows(mine["matches"]) == rows(indexed["matches"])
    assert mine["epsilon"] == indexed["epsilon"] and mine["query"]["clip"] == "walk/walk_00.bvh"
    assert mine["request"]["clip"] == up["id"]


def test_a_new_clip_uploaded_finds_what_search_query_file_finds(client, cfg, tmp_path: Path) -> None:
    """A demo walk of another seed (not indexed): its webs are built in the search worker and kept
    with the upload; the matches, ε and registration are the CLI's ``--query-file`` ones."""
    from motionweb.store.bvh import write_bvh
    from motionweb.store.demo.corpus import generate_clip

    walk, _ = generate_clip("walk", 0, 1234, 30.0)
    write_bvh(walk, tmp_path / "new_walk.bvh")
    up = upload(client, "new_walk.bvh", (tmp_path / "new_walk.bvh").read_text())
    assert up["bytes"] > 0
    res = search(client, clip=up["id"], tiers=3)
    request = QueryRequest(clip="new_walk.bvh", tiers=3, out=str(tmp_path / "o"), **WINDOW)
    cli = query.fn(cfg, request, plan_query(cfg, request, read_motion(tmp_path / "new_walk.bvh", unit="m")))
    assert cli["matches"] and "walk" in {m["category"] for m in cli["matches"]}
    assert rows(res["matches"], res["query"]["clip"]) == rows(cli["matches"], cli["query"]["clip"]) and res["epsilon"] == pytest.approx(cli["epsilon"], rel=1e-12)
    q = res["query"]
    assert q["id"] == up["id"] and q["clip"].startswith("file:" + up["id"]) and q["category"] == ""
    status = client.get("/api/status").json()["uploads"]
    kept = status["bytes"]
    assert status["uploads"] >= 1 and up["bytes"] < kept <= status["max_bytes"] == int(cfg.app.upload_mb * 2**20)
    assert client.get(f"/api/uploads/{up['id']}").json()["bytes"] > up["bytes"]  # its webs are kept with it
    again = search(client, clip=up["id"], tiers=3, start=1.2)  # kept webs: another window, nothing rebuilt
    assert again["query"]["start_frame"] == 36 and client.get("/api/status").json()["uploads"]["bytes"] == kept
    # the query's pose and download, and the registration (its features from the upload)
    pose = client.get(f"/api/results/{res['result']}/nodes/0/pose", params={"registered": True}).json()
    assert pose["id"] == up["id"] and pose["frames"] == q["end_frame"] - q["start_frame"] + 1
    reg = client.get(f"/api/results/{res['result']}/registration").json()
    assert [n["rank"] for n in reg["nodes"]] == list(range(len(res["matches"]) + 1))
    bvh = client.get(f"/api/results/{res['result']}/nodes/0/bvh")
    assert bvh.status_code == 200 and bvh.text.startswith("HIERARCHY") and "new_walk" in bvh.headers["content-disposition"]
    m1 = client.get(f"/api/results/{res['result']}/nodes/1/pose").json()
    assert m1["path"] == res["matches"][0]["clip"]


@pytest.mark.parametrize(("body", "status", "field"), [
    ({"clip": "up-0123456789abcdef"}, 404, "clip"),
    ({"clip": "up-../../etc/passwd"}, 404, "clip"),
    ({"start": 1.0, "end": 99.0}, 400, "end"),
    ({"start": -1.0, "end": 1.0}, 400, "start"),
    ({"start": 2.0, "end": 1.0}, 400, "end"),
    ({"path": "/etc/passwd"}, 400, "path"),
])
def test_a_bad_upload_id_or_window_answers_json_naming_the_field(client, cfg, body, status, field) -> None:
    text = (Path(cfg.corpus.path) / "run" / "run_01.bvh").read_text().replace("\n", "\r\n")  # not the indexed bytes
    up = upload(client, "run copy", text)
    r = client.post("/api/search", json={"clip": up["id"], **WINDOW, **body})
    assert r.status_code == status, r.text
    err = r.json()["error"]
    assert err.startswith(f"{field}:") or f" {field}" in err or f"{field} " in err, err
    assert "Traceback" not in r.text
    assert search(client, clip=up["id"])["matches"]  # the service goes on
    assert search(client, clip="walk_00")["matches"]


def test_the_upload_cache_is_bounded_by_bytes() -> None:
    """Webs kept with an upload count toward ``app.upload_mb``: over it, the least recently used
    upload goes (the newest stays, even alone over the bound); another generation's webs replace
    the kept ones."""
    import numpy as np
    from motionweb.flows.app.engine import NotFound
    from motionweb.flows.app.params import AppParams
    from motionweb.flows.app.uploads import UploadBody, Uploads
    from motionweb.store.demo.corpus import generate_clip

    walk, _ = generate_clip("walk", 0, 1234, 30.0)
    ups = Uploads(AppParams(upload_mb=1.0), lambda job: walk)

    def webs(mb: float):  # a build of ``mb`` MiB (float64)
        return lambda u: ({"features": np.zeros(int(mb * 2**17))}, {})

    a = ups.add(UploadBody(name="a", bvh="A", unit="m"), "m", None)["id"]
    ups.query_webs(a, "g1", webs(0.6))
    assert ups.stats()["bytes"] >= 0.6 * 2**20 and ups.get(a).webs.keys() == {"g1"}
    assert ups.query_webs(a, "g1", lambda u: pytest.fail("kept webs are not rebuilt"))
    b = ups.add(UploadBody(name="b", bvh="B", unit="m"), "m", None)["id"]
    ups.query_webs(b, "g1", webs(0.6))  # a (least recently used) goes
    with pytest.raises(NotFound, match="upload the clip again"):
        ups.get(a)
    ups.query_webs(b, "g2", webs(2.0))  # alone over the bound: kept, g1's dropped
    assert ups.get(b).webs.keys() == {"g2"} and ups.stats()["uploads"] == 1


def test_an_upload_whose_length_is_no_whole_number_of_web_frames_is_searched(client, cfg) -> None:
    """A clip of 4k + 3 frames at 120 Hz lasts a fractional number of the index's 30 Hz frames: its
    webs are built and searched (they once failed with "end: ... outside clip"), and a window
    ending at its very end ends on its last web frame."""
    text = (Path(cfg.corpus.path) / "walk" / "walk_01.bvh").read_text()
    head, _, body = text.partition("MOTION\n")
    lines = body.splitlines()
    frames = [ln for ln in lines[2:] if ln.strip()]
    n = len(frames) - (len(frames) - 3) % 4  # 4k + 3 frames: (n - 1) / 120 s = k + 0.5 web frames
    text = head + f"MOTION\nFrames: {n}\nFrame Time: {1 / 120:.8f}\n" + "\n".join(frames[:n]) + "\n"
    up = upload(client, "fast walk.bvh", text)
    duration = up["duration"]
    assert duration == pytest.approx((n - 1) / 120)
    assert abs(duration * 30 - round(duration * 30)) > 0.2  # not a whole number of 30 Hz frames
    res = search(client, clip=up["id"], start=0.0, end=duration, quantile=0.8)
    assert res["query"]["end_frame"] == int(duration * 30)
