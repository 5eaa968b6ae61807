"""The retime stage's defaults live in one place, ``RetimeParams`` (issue 23): calling the stage
in-process with ``RetimeParams()`` writes the same bytes as ``motionweb retime`` with the default
config, and that command's output is the tool's own (no HiGHS banner, no traceback)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from motionweb.store.bvh import write_bvh
from motionweb.store.demo.corpus import write_demo_corpus
from motionweb.store.formats import read_motion
from motionweb.tasks.retime import RetimeParams, prepare, report, retime_plan

#: report fields that depend on the run, not on the result: wall times and the output path
RUN_FIELDS = ("timings_s", "output")


def motionweb_cli() -> list[str]:
    """The installed ``motionweb`` command (the module where no script sits beside this Python)."""
    script = Path(sys.executable).with_name("motionweb")
    return [str(script)] if script.is_file() else [sys.executable, "-m", "motionweb.flows.commands.cli"]


def cli_env(tmp_path: Path) -> dict[str, str]:
    """A new user's environment: no Prefect server configured, a Prefect home of its own."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("PREFECT_API")}
    env["PREFECT_HOME"] = str(tmp_path / "prefect")
    return env


def without_run_fields(text: str) -> dict:
    rep = json.loads(text)
    for key in RUN_FIELDS:
        rep.pop(key, None)
    return rep


@pytest.fixture(scope="module")
def demo_jump(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("demo")
    write_demo_corpus(root, variants_per_category=0, variants={"jump": 1})
    return root / "jump" / "jump_00.bvh"


def test_the_stage_with_its_defaults_writes_what_the_cli_writes_and_the_cli_is_quiet(demo_jump: Path,
                                                                                       tmp_path: Path) -> None:
    """Design §8: ``prepare`` / ``retime_plan`` / ``report`` with ``RetimeParams()`` give the BVH and
    the JSON report (its timing-independent fields) of ``motionweb retime --duration 2.5`` run as a
    new user runs it, and that run prints neither HiGHS's banner nor a traceback."""
    cli_out = tmp_path / "cli" / "jump_retimed.bvh"
    r = subprocess.run([*motionweb_cli(), "retime", str(demo_jump), "--out", str(cli_out), "--duration", "2.5"],
                       cwd=tmp_path, env=cli_env(tmp_path), capture_output=True, text=True, timeout=600, check=False)
    assert r.returncode == 0, (r.stdout, r.stderr)
    noise = r.stdout + r.stderr
    assert "HiGHS" not in noise and "Traceback" not in noise, noise

    opts = RetimeParams()
    motion = read_motion(demo_jump)
    plan = prepare(motion, opts, up_axis="y")
    retimed, res = retime_plan(plan, 2.5, [], opts)
    own = tmp_path / "own" / "jump_retimed.bvh"
    own.parent.mkdir()
    write_bvh(retimed, own)
    rep = report(plan, res)
    assert own.read_bytes() == cli_out.read_bytes()
    # the report's bytes as the flow writes them (json.dumps, indent 1), the run's fields left out
    ours = json.dumps(without_run_fields(json.dumps(rep, indent=1)), indent=1)
    assert ours == json.dumps(without_run_fields(cli_out.with_suffix(".json").read_text()), indent=1)


def test_a_closing_local_cluster_s_heartbeat_traceback_is_dropped() -> None:
    """Design §10: the message a Dask worker logs with a traceback when its last heartbeat meets the
    closing scheduler is dropped while ``quiet_heartbeat`` is on, and only that message."""
    import logging

    from motionweb.flows.runtime.workers import HEARTBEAT_LOST, quiet_heartbeat

    log = logging.getLogger("distributed.worker")
    seen: list[str] = []

    class Keep(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            seen.append(record.getMessage())

    handler = Keep(level=logging.DEBUG)
    log.addHandler(handler)
    try:
        quiet_heartbeat()
        quiet_heartbeat()  # idempotent
        try:
            raise OSError("stream closed")
        except OSError:
            log.exception(HEARTBEAT_LOST + ".")
        log.error("another worker error")
        quiet_heartbeat(on=False)
        log.error(HEARTBEAT_LOST + ".")
    finally:
        quiet_heartbeat(on=False)
        log.removeHandler(handler)
    assert seen == ["another worker error", HEARTBEAT_LOST + "."]


def test_other_stages_with_their_defaults_write_what_the_cli_writes(demo_jump: Path, tmp_path: Path) -> None:
    """The same for guided warping (``guided_warp`` with ``WarpParams()``), mirroring
    (``MirrorParams()``) and foot-slide cleanup (``BlendParams()``): each stage called with its
    parameter model's defaults gives the bytes the CLI writes with the default config."""
    from motionweb.tasks.blend import BlendParams
    from motionweb.tasks.cleanup import cleanup
    from motionweb.tasks.guided_warp import WarpParams, guided_warp
    from motionweb.tasks.mirror import MirrorParams, mirror

    motion = read_motion(demo_jump)
    n_out = round(2.5 * motion.fps) + 1
    own = {"warp": guided_warp(motion, None, n_out=n_out, keytimes=(), params=WarpParams()).motion,
           "mirror": mirror(motion, MirrorParams()).motion,
           "cleanup": cleanup(motion, BlendParams(), up="y").motion}
    runs = {"warp": ["warp", str(demo_jump), "--duration", "2.5"], "mirror": ["mirror", str(demo_jump)],
            "cleanup": ["cleanup", str(demo_jump)]}
    for name, args in runs.items():
        cli_out = tmp_path / "cli" / f"{name}.bvh"
        r = subprocess.run([*motionweb_cli(), *args, "--out", str(cli_out)], cwd=tmp_path, env=cli_env(tmp_path),
                           capture_output=True, text=True, timeout=600, check=False)
        assert r.returncode == 0, (name, r.stdout, r.stderr)
        mine = tmp_path / "own" / f"{name}.bvh"
        mine.parent.mkdir(exist_ok=True)
        write_bvh(own[name], mine)
        assert mine.read_bytes() == cli_out.read_bytes(), name


def test_motionweb_retime_with_the_default_config_hands_the_models_defaults_down(demo_jump: Path, tmp_path: Path,
                                                                                monkeypatch) -> None:
    """Design §8: the run ``motionweb retime --duration 2.5`` makes with the packaged default config
    gives the lower-level functions (contacts, polygons, objective, spline, path timing) the groups
    of ``RetimeParams()`` and their values — the only place those defaults are written."""
    import inspect

    from motionweb.flows.config import load_config
    from motionweb.flows.retime import retime_flow
    from motionweb.tasks.retime import ContactParams, PolygonParams, pipeline

    seen: dict[str, list[dict]] = {}
    for name in ("contacts_for", "original_forces", "feasible_polygons", "bake", "optimize_timing", "path_timing"):
        real = getattr(pipeline, name)

        def spy(*args, _real=real, _name=name, **kwargs):
            seen.setdefault(_name, []).append(inspect.signature(_real).bind(*args, **kwargs).arguments)
            return _real(*args, **kwargs)

        monkeypatch.setattr(pipeline, name, spy)
    monkeypatch.chdir(tmp_path)
    cfg = load_config()
    assert cfg.retime == RetimeParams()
    retime_flow.fn(str(demo_jump), cfg, str(tmp_path / "out.bvh"), duration=2.5)

    d = RetimeParams()
    (rule,) = [c["rule"] for c in seen["contacts_for"]]
    assert type(rule) is ContactParams and rule == d.contacts
    for name in ("original_forces", "feasible_polygons"):
        assert [type(c["opts"]) for c in seen[name]] == [PolygonParams] and seen[name][0]["opts"] == d.polygons
    assert seen["original_forces"][0]["margin"] == d.torque_margin
    (bake,) = seen["bake"]
    assert (bake["alpha"], bake["beta"]) == (d.spline.alpha, d.spline.beta)
    (opt,) = seen["optimize_timing"]
    assert (opt["samples_per_frame"], opt["knots_per_second"], opt["speed_max"]) == (
        d.spline.samples_per_frame, d.spline.knots_per_second, d.polygons.speed_max)
    assert all(c["samples_per_frame"] == d.spline.samples_per_frame for c in seen.get("path_timing", []))
