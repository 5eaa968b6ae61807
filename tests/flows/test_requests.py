"""One request model per command (flows/commands/requests.py, issue 23): the CLI, the forwarding client and
the service's API take the same model, so a bad request gets the same message naming its field
from each front door, and a request survives the wire unchanged."""

from __future__ import annotations

import pytest
from motionweb.flows.commands.cli import app
from motionweb.flows.commands.requests import (
    BlendRequest,
    QueryRequest,
    RetimeRequest,
    SearchQuery,
    SpaceRequest,
    SynthesizeRequest,
    WarpRequest,
    parse,
)
from typer.testing import CliRunner

runner = CliRunner()


@pytest.mark.parametrize(("model", "fields", "message"), [
    (QueryRequest, {"clip": "a", "start": 1.0, "end": 0.5}, "must end after it starts"),
    (QueryRequest, {"clip": "a", "start": 0.0, "end": 1.0, "threshold": 1.0, "quantile": 0.5}, "at most one of"),
    (QueryRequest, {"clip": "a", "start": 0.0, "end": 1.0, "quantile": 1.0}, "quantile must lie in (0, 1)"),
    (QueryRequest, {"clip": "a", "start": 0.0, "end": 1.0, "tiers": 0}, "tiers must be ≥ 1"),
    (QueryRequest, {"clip": "a", "start": 0.0, "end": float("nan")}, "end must be a finite number"),
    (QueryRequest, {"clip": "", "start": 0.0, "end": 1.0}, "clip: String should have at least 1"),
    (SearchQuery, {"clip": "a", "start": 0.0, "end": 1.0, "out": "/tmp"}, "out: Extra inputs"),
    (SpaceRequest, {"clip": "a", "start": 0.0, "end": 1.0, "param": "final_root", "samples": 0}, "--samples must be ≥ 1"),
    (WarpRequest, {"input": "a.bvh", "out": "b.bvh"}, "exactly one of --duration"),
    (WarpRequest, {"input": "a.bvh", "out": "b.bvh", "duration": -1.0}, "--duration must be positive"),
    (RetimeRequest, {"input_path": "a.bvh", "out": "b.bvh"}, "--duration SECONDS and/or --keytime"),
    (RetimeRequest, {"input_path": "a.bvh", "out": "b.bvh", "duration": 1.0, "mass": {"lfemur": 0.0}},
     "--mass lfemur=0"),
    (RetimeRequest, {"input_path": "a.bvh", "out": "b.bvh", "duration": 1.0, "gravity": [0.0, -9.8]},
     "gravity: List should have at least 3"),
    (SynthesizeRequest, {"target": []}, "target: List should have at least 1"),
    (BlendRequest, {"weights": {"a": float("inf")}}, "weight of 'a' must be a finite number"),
])
def test_bad_requests_name_the_problem(model, fields, message) -> None:
    with pytest.raises(ValueError, match=None) as err:
        parse(model, **fields)
    assert message in str(err.value), str(err.value)
    assert "Value error," not in str(err.value)


def test_a_request_survives_the_wire() -> None:
    """What the client sends (``wire()``) is what the service's model reads back, ``register``
    included (the field is ``register_``: ABCMeta.register)."""
    q = QueryRequest(clip="walk_00", start=1.0, end=2.5, tiers=3, register=True, out="o")
    assert q.register_ is True and q.wire()["register"] is True
    assert QueryRequest(**q.wire()) == q
    assert q.search_query() == SearchQuery(clip="walk_00", start=1.0, end=2.5, tiers=3, register=True)
    assert list(q.wire()) == ["clip", "start", "end", "threshold", "quantile", "tiers", "all_categories",
                              "register", "export", "out", "format"]  # the order matches.json records
    s = SpaceRequest(clip="walk_00", start=1.0, end=2.5, param="final_root", quantile=0.8)
    assert list(s.wire()) == ["clip", "start", "end", "param", "threshold", "quantile", "samples", "out"]
    assert s.query() == QueryRequest(clip="walk_00", start=1.0, end=2.5, quantile=0.8)


def test_the_cli_and_the_api_give_the_same_message(app_store) -> None:
    """``motionweb search`` with the query ending before it starts fails before any store is read,
    with the message the service's /api/search answers for the same body."""
    from fastapi.testclient import TestClient
    from motionweb.flows.app.api import create_app
    from motionweb.flows.app.engine import Engine
    from motionweb.flows.config import load_config

    r = runner.invoke(app, ["search", str(app_store), "--clip", "walk_00", "--start", "2", "--end", "1",
                            "--quantile", "0.5"])
    assert r.exit_code == 2
    cli = r.output.strip().removeprefix("error: ")
    api = TestClient(create_app(Engine(load_config(app_store)))).post(
        "/api/search", json={"clip": "walk_00", "start": 2, "end": 1, "quantile": 0.5})
    assert api.status_code == 400 and api.json()["error"] == cli, (cli, api.json())
    assert "must end after it starts" in cli


@pytest.mark.parametrize("args, message", [
    (["preview", "x.bvh", "--out", "x.gif", "--fps", "0"], "fps: Input should be greater than 0"),
    (["preview", "x.bvh", "--out", "x.gif", "--up", "w"], "up: Input should be 'x', 'y' or 'z'"),
    (["gc", "nope.yaml", "--keep", "0"], "keep: Input should be greater than or equal to 1"),
    (["catalog", "no-such-corpus"], "no-such-corpus"),
])
def test_housekeeping_commands_check_their_request_first(args, message, tmp_path) -> None:
    """catalog, preview and gc build their request model (flows/commands/requests.py) before any work:
    a bad option is one line naming its field, exit 2, nothing written."""
    res = runner.invoke(app, args)
    assert res.exit_code == 2, res.output
    assert message in res.output
    assert "Traceback" not in res.output
    assert not (tmp_path / "x.gif").exists()


def test_verify_exits_1_on_a_store_never_indexed_and_2_on_a_bad_config(tmp_path) -> None:
    """verify runs on run_command: a store with no generation is an error (exit 2, one line), a
    damaged one exit 1 (tests/flows/test_store_integrity.py)."""
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"store:\n  path: {tmp_path / 'store'}\n")
    res = runner.invoke(app, ["verify", str(cfg)])
    assert res.exit_code == 2 and "was never indexed" in res.output, res.output
    res = runner.invoke(app, ["verify", str(tmp_path / "missing.yaml")])
    assert res.exit_code == 2 and "missing.yaml" in res.output, res.output
