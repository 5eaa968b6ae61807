"""The service's motion spaces (KG04 §4): the API against flows/space.py's own answers, bad
input as JSON with the CLI's messages, and `motionweb synthesize` / `blend` forwarded to a
running service writing the bytes of a local run."""

from __future__ import annotations

import re

import numpy as np
import pytest
from fastapi.testclient import TestClient
from motionweb.flows.app.api import create_app
from motionweb.flows.app.engine import Engine
from motionweb.flows.commands.cli import app as cli
from motionweb.flows.config import load_config
from motionweb.flows.space import list_spaces, load_space
from motionweb.store.bvh import format_bvh
from motionweb.tasks.features import joint_positions_m
from typer.testing import CliRunner


@pytest.fixture(scope="module")
def cfg(app_store):
    return load_config(app_store)


@pytest.fixture(scope="module")
def client(cfg, app_space):
    return TestClient(create_app(Engine(cfg, warm=False)))


def test_spaces_are_listed_with_their_sampled_cloud(client, cfg, app_space) -> None:
    listed = client.get("/api/spaces").json()["spaces"]
    assert listed == list_spaces(cfg) and app_space in [s["id"] for s in listed]
    d = client.get(f"/api/spaces/{app_space[:10]}").json()
    st = load_space(cfg, app_space)
    assert d["id"] == app_space and d["dim"] == 3 and d["param"] == "position:RightHand@0.75"
    assert d["names"] == st.clips and d["samples_total"] == len(st.samples)
    np.testing.assert_allclose(d["samples"], st.samples, atol=6e-5)
    np.testing.assert_allclose(d["example_params"], st.example_params, atol=6e-5)
    np.testing.assert_allclose(d["lo"], st.samples.min(axis=0), atol=6e-5)


def test_synthesis_equals_the_stored_spaces_own(client, cfg, app_space) -> None:
    st = load_space(cfg, app_space)
    for target, outside in ((st.samples[len(st.example_params) + 3] + 0.002, False),
                            (st.samples.max(axis=0) + 0.5, True)):
        r = client.post(f"/api/spaces/{app_space}/synthesize", json={"target": target.tolist(), "bvh": True})
        assert r.status_code == 200, r.text
        got = r.json()
        motion, syn = st.synthesize(target)
        assert got["outside"] is outside and syn.outside is outside
        np.testing.assert_allclose(got["achieved"], syn.achieved, atol=1e-12)
        assert got["error"] == pytest.approx(np.linalg.norm(syn.achieved - target), abs=1e-9)
        assert got["bvh"] == format_bvh(motion) and got["frames"] == motion.n_frames
        pose = np.asarray(got["pose"]["positions"]).reshape(got["pose"]["frames"], -1, 3)
        np.testing.assert_allclose(pose, joint_positions_m(motion, "y"), atol=6e-4)
        assert got["weights"] == {n: w for n, w in zip(st.clips, syn.weights.tolist(), strict=True) if w != 0}
    assert got["error"] > 0.1  # the far target is reported with its distance


def test_syntheses_and_blends_go_to_the_recorder_like_searches(cfg, app_space) -> None:
    seen: list[tuple[str, dict, dict]] = []
    recording = TestClient(create_app(Engine(cfg, on_query=lambda *rec: seen.append(rec), warm=False)))
    st = load_space(cfg, app_space)
    target = st.samples[len(st.example_params) + 1]
    assert recording.post(f"/api/spaces/{app_space}/synthesize", json={"target": target.tolist()}).status_code == 200
    weights = {st.clips[0]: 0.5, st.clips[1]: 0.5}
    assert recording.post(f"/api/spaces/{app_space}/blend", json={"weights": weights}).status_code == 200
    assert recording.post(f"/api/spaces/{app_space}/synthesize", json={"target": [1.0]}).status_code == 400
    assert [k for k, _, _ in seen] == ["synthesize", "blend"]  # a refused request is not a run
    (_, p1, o1), (_, p2, o2) = seen
    assert p1 == {"space": app_space, "target": target.tolist()} and o1["error"] >= 0
    assert p2 == {"space": app_space, "weights": weights} and o2["frames"] > 0


def test_blend_equals_the_stored_spaces_own(client, cfg, app_space) -> None:
    st = load_space(cfg, app_space)
    w = {st.clips[0]: 0.25, st.clips[1]: 0.75}
    got = client.post(f"/api/spaces/{app_space}/blend", json={"weights": w, "bvh": True, "pose": False}).json()
    assert got["bvh"] == format_bvh(st.blend(w)) and "pose" not in got
    r = client.post(f"/api/spaces/{app_space}/blend", json={"weights": {st.clips[0]: 0.5}})
    assert r.status_code == 400 and r.json()["error"] == "weights must sum to 1, got 0.5"


@pytest.mark.parametrize("route, body, status, message", [
    ("synthesize", {"target": [0.1, 0.2]}, 400, "--target has 2 values; space parameter position:RightHand@0.75 has 3"),
    ("synthesize", {"target": [0.1, 0.2, 0.3, 0.4]}, 400, "target: List should have at most 3 items"),
    ("synthesize", {"target": [0.1, 1e9, 0.3]}, 400, "must be finite and within"),
    ("synthesize", {"target": "0.1,0.2,0.3"}, 400, "target: Input should be a valid list"),
    ("synthesize", {"target": [0.1, 0.2, 0.3], "path": "/etc"}, 400, "Extra inputs are not permitted"),
    ("blend", {"weights": {"walk/nope.bvh": 1.0}}, 400, "'walk/nope.bvh' is not an example of this space"),
])
def test_bad_space_requests_answer_json_with_the_clis_message(client, app_space, route, body, status, message) -> None:
    r = client.post(f"/api/spaces/{app_space}/{route}", json=body)
    assert r.status_code == status and message in r.json()["error"], r.text


def test_unknown_spaces_are_404_and_ids_are_never_paths(client) -> None:
    r = client.get("/api/spaces/ffffffff")
    assert r.status_code == 404 and "motion space 'ffffffff' is not stored" in r.json()["error"]
    for bad in ("zz", "ABC", "0x1f", "a.b"):
        r = client.post(f"/api/spaces/{bad}/synthesize", json={"target": [0, 0, 0]})
        assert r.status_code == 404 and "hexadecimal" in r.json()["error"], r.text
    r = client.post("/api/spaces/..%2F..%2Fetc/synthesize", json={"target": [0, 0, 0]})
    assert r.status_code == 404 and r.json() == {"error": "Not Found"}  # no such route, answered as JSON


def test_synthesize_and_blend_are_forwarded_and_write_a_local_runs_bytes(running, app_store, app_space, cfg, tmp_path,
                                                                         monkeypatch) -> None:
    st = load_space(cfg, app_space)
    target = ",".join(f"{v:.5f}" for v in st.samples[7] + 0.001)
    w = [f"--weights={st.clips[0]}=0.4", f"--weights={st.clips[1]}=0.6"]
    runs = {}
    for where in ("service", "local"):
        if where == "local":
            monkeypatch.setenv("MOTIONWEB_APP_DIR", str(tmp_path / "no-service"))
        s = CliRunner().invoke(cli, ["synthesize", app_space[:12], "--target", target, "--out", str(tmp_path / f"s-{where}.bvh"),
                                     "--config", str(app_store)])
        b = CliRunner().invoke(cli, ["blend", app_space[:12], *w, "--out", str(tmp_path / f"b-{where}.bvh"),
                                     "--config", str(app_store)])
        assert s.exit_code == 0 and b.exit_code == 0, s.output + b.output
        assert ("by the service at" in s.output + b.output) == (where == "service")
        runs[where] = [re.sub(r" \(by the service at [^)]*\)", "", r.output.replace(f"-{where}.bvh", ".bvh"))
                       for r in (s, b)]
        if where == "service":  # a GLB is written by the local run, the service only makes BVH
            g = CliRunner().invoke(cli, ["blend", app_space[:12], *w, "--out", str(tmp_path / "b.glb"),
                                         "--config", str(app_store)])
            assert g.exit_code == 0 and "by the service" not in g.output, g.output
            assert (tmp_path / "b.glb").read_bytes()[:4] == b"glTF"
        bad = CliRunner().invoke(cli, ["synthesize", app_space[:12], "--target", "1,2", "--out", str(tmp_path / "x.bvh"),
                                       "--config", str(app_store)])
        assert bad.exit_code == 2 and "--target has 2 values" in bad.output and "Traceback" not in bad.output
    assert runs["service"] == runs["local"] and "achieved" in runs["local"][0] and "wrote" in runs["local"][1]
    for name in ("s", "b"):
        assert (tmp_path / f"{name}-service.bvh").read_bytes() == (tmp_path / f"{name}-local.bvh").read_bytes()
