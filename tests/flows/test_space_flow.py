"""`motionweb parameterize` / `synthesize` / `blend` end to end on a small demo corpus of walks."""

from __future__ import annotations

import numpy as np
import pytest
from motionweb.flows.commands.cli import app
from motionweb.flows.config import load_config
from motionweb.flows.space import list_spaces, load_space
from motionweb.store.bvh import read_bvh
from motionweb.store.demo.corpus import write_demo_corpus
from typer.testing import CliRunner

runner = CliRunner()


@pytest.fixture(scope="module")
def space(prefect_harness, tmp_path_factory):
    """(config path, space id, CLI output) of a final-root walk space over 6 demo walks."""
    mp = pytest.MonkeyPatch()
    for var, value in [("PREFECT_LOGGING_LEVEL", "WARNING"), ("DASK_LOGGING__DISTRIBUTED", "warning")]:
        mp.setenv(var, value)
    work = tmp_path_factory.mktemp("space")
    from motionweb.store.demo.corpus import CATEGORIES

    write_demo_corpus(work / "corpus", variants={c: (6 if c == "walk" else 0) for c in CATEGORIES})
    cfg = work / "config.yaml"
    cfg.write_text("corpus: {path: corpus, length_unit: m}\nstore: {path: store}\noutput: out\n"
                   "dask: {processes: false}\nparameterize: {samples: 300}\n")
    r = runner.invoke(app, ["index", str(cfg), "--no-progress"])
    assert r.exit_code == 0, r.output
    r = runner.invoke(app, ["parameterize", str(cfg), "--clip", "walk_00", "--start", "0.5", "--end", "2.5",
                            "--quantile", "0.9", "--param", "final_root"])
    mp.undo()
    assert r.exit_code == 0, r.output
    sid = r.output.split()[1].rstrip(":")
    return cfg, sid, r.output


def test_parameterize_stores_a_space_and_its_plot(space) -> None:
    cfg_path, sid, output = space
    cfg = load_config(cfg_path)
    listed = list_spaces(cfg)
    assert [s["id"] for s in listed] == [sid]
    assert listed[0]["param"] == "final_root" and listed[0]["examples"] >= 3
    png = cfg_path.parent / "out" / f"space-{sid[:12]}.png"
    assert png.stat().st_size > 0 and str(png) in output.replace("\n", "")
    st = load_space(cfg, sid[:10])
    assert st.id == sid and st.samples.shape[1] == 2
    # the examples' stored parameters are what the reloaded examples give (the space is reproducible)
    np.testing.assert_allclose(st.example_params, st.space.fn(st.space.examples, np.eye(st.space.examples.n)),
                               atol=1e-9)


def test_synthesize_hits_an_inside_target_and_projects_an_outside_one(space, tmp_path) -> None:
    cfg_path, sid, _ = space
    st = load_space(load_config(cfg_path), sid)
    target = st.samples[len(st.example_params) + 7] + 0.003
    out = tmp_path / "s.bvh"
    r = runner.invoke(app, ["synthesize", sid[:12], "--target", ",".join(f"{v:.5f}" for v in target),
                            "--out", str(out), "--config", str(cfg_path)])
    assert r.exit_code == 0, r.output
    m = read_bvh(out)
    motion, syn = st.synthesize(target)
    assert syn.error < 0.02 and not syn.outside
    assert m.n_frames == motion.n_frames
    np.testing.assert_allclose(m.root_positions, motion.root_positions, atol=1e-5)
    far = runner.invoke(app, ["synthesize", sid[:12], "--target", "40,40", "--out", str(tmp_path / "f.bvh"),
                              "--config", str(cfg_path)])
    assert far.exit_code == 0 and "projected" in far.output


def test_blend_with_weight_one_reproduces_the_example_path(space, tmp_path) -> None:
    cfg_path, sid, _ = space
    st = load_space(load_config(cfg_path), sid)
    name = st.clips[1]
    out = tmp_path / "b.bvh"
    r = runner.invoke(app, ["blend", sid[:12], "--weights", f"{name}=1", "--out", str(out), "--config", str(cfg_path)])
    assert r.exit_code == 0, r.output
    m = read_bvh(out)
    end = m.root_positions[-1] - m.root_positions[0]
    assert np.hypot(end[0], end[2]) == pytest.approx(np.linalg.norm(st.example_params[1]), abs=0.05)


@pytest.mark.parametrize(("args", "message"), [
    (["synthesize", "{sid}", "--target", "1,2,3", "--out", "x.bvh"], "has 3 values; space parameter final_root has 2"),
    (["synthesize", "{sid}", "--target", "a,b", "--out", "x.bvh"], "expected numbers separated by commas"),
    (["synthesize", "ffffffffff", "--target", "1,2", "--out", "x.bvh"], "is not stored"),
    (["blend", "{sid}", "--weights", "walk_00=0.5", "--out", "x.bvh"], "weights must sum to 1"),
    (["blend", "{sid}", "--weights", "nope=1", "--out", "x.bvh"], "'nope' is not an example"),
    (["blend", "{sid}", "--weights", "walk_00", "--out", "x.bvh"], "expected CLIP=WEIGHT"),
])
def test_bad_space_requests_fail_with_one_line(space, args: list[str], message: str) -> None:
    cfg_path, sid, _ = space
    r = runner.invoke(app, [a.format(sid=sid[:12]) for a in args] + ["--config", str(cfg_path)])
    assert r.exit_code == 2, r.output
    assert message in r.output and "Traceback" not in r.output


def no_flow(*args, **kwargs):
    raise AssertionError("the flow started although the request is bad")


@pytest.mark.parametrize(("args", "message"), [
    (["--param", "position:Nose@0.5", "--quantile", "0.9"], "unknown joint 'Nose'"),
    (["--param", "position:LeftHand@9", "--quantile", "0.9"], "outside the query"),
    (["--param", "wiggle", "--quantile", "0.9"], "unknown kind 'wiggle'"),
    (["--param", "custom:json.dumps", "--quantile", "0.9"], "custom:json.dumps failed: TypeError"),
    (["--param", "final_root", "--samples", "0", "--quantile", "0.9"], "--samples must be ≥ 1"),
    (["--param", "final_root", "--threshold", "1e-9"], "found 1 motions (the query included); a 2-D parameter "
                                                       "needs at least 3"),
])
def test_bad_parameterize_requests_fail_with_one_line_before_the_flow(space, args: list, message: str,
                                                                     monkeypatch) -> None:
    cfg_path, _, _ = space
    monkeypatch.setattr("motionweb.flows.space.parameterize", no_flow)
    base = ["parameterize", str(cfg_path), "--clip", "walk_00", "--start", "0.5", "--end", "2.5"]
    r = runner.invoke(app, base + args)
    assert r.exit_code == 2, r.output
    assert message in r.output and "Traceback" not in r.output
    assert len(r.output.strip().splitlines()) == 1, r.output


@pytest.mark.parametrize(("section", "message"), [
    ("parameterize: {registration: flight}", "parameterize.registration = flight, but the query"),
    ("blend: {feet: {left: Nope}}", "unknown left ankle joint 'Nope'"),
])
def test_bad_config_for_a_space_fails_with_one_line_before_the_flow(space, section: str, message: str,
                                                                   monkeypatch) -> None:
    cfg_path, _, _ = space
    other = cfg_path.parent / "other.yaml"
    other.write_text(cfg_path.read_text().replace("parameterize: {samples: 300}\n", "") + section + "\n")
    monkeypatch.setattr("motionweb.flows.space.parameterize", no_flow)
    r = runner.invoke(app, ["parameterize", str(other), "--clip", "walk_00", "--start", "0.5", "--end", "2.5",
                            "--quantile", "0.9", "--param", "final_root"])
    assert r.exit_code == 2, r.output
    assert message in r.output and len(r.output.strip().splitlines()) == 1, r.output


def test_an_error_inside_the_flow_is_one_line_too(space, monkeypatch) -> None:
    """Were the index to change between the checks and the flow, the flow's own check fails: one
    line at the CLI, and Prefect's run loggers pass on no record of it (no traceback on stderr)."""
    import logging

    cfg_path, _, _ = space
    monkeypatch.setattr("motionweb.flows.space.plan_space", lambda cfg, request: 0)
    seen: list[logging.LogRecord] = []

    class Keep(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            seen.append(record)

    keep = Keep(logging.DEBUG)
    loggers = [logging.getLogger(n) for n in ("prefect.flow_runs", "prefect.task_runs")]
    levels = [lg.level for lg in loggers]
    for lg in loggers:  # the CLI sets PREFECT_LOGGING_LEVEL=WARNING: see the run's INFO lines too
        lg.addHandler(keep)
        lg.setLevel(logging.DEBUG)
    try:
        r = runner.invoke(app, ["parameterize", str(cfg_path), "--clip", "walk_00", "--start", "0.5", "--end",
                                "2.5", "--threshold", "1e-9", "--param", "final_root"])
    finally:
        for lg, level in zip(loggers, levels, strict=True):
            lg.removeHandler(keep)
            lg.setLevel(level)
    assert r.exit_code == 2, r.output
    assert "needs at least 3" in r.output and "Traceback" not in r.output
    assert seen, f"the flow ran and logged: {r.output}"
    assert not [x for x in seen if x.exc_info or x.levelno >= logging.ERROR], [x.getMessage() for x in seen]
