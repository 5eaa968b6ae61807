"""The motionweb CLI: help on every command, catalog table/JSON, preview GIF, clear errors."""

from __future__ import annotations

import json
from pathlib import Path

from fixtures import tiny_motion
from motionweb.flows.commands.cli import app
from motionweb.store.bvh import write_bvh
from typer.testing import CliRunner

runner = CliRunner()


def test_help_on_every_command() -> None:
    result = runner.invoke(app, ["--help"])
    assert result.exit_code == 0
    commands = [c.name or c.callback.__name__ for c in app.registered_commands]
    assert {"catalog", "preview", "demo"} <= set(commands)
    for name in commands:
        r = runner.invoke(app, [name.replace("_", "-"), "--help"])
        assert r.exit_code == 0, (name, r.output)
        assert "Usage" in r.output


def test_catalog_table_and_json(tmp_path: Path) -> None:
    (tmp_path / "walk").mkdir()
    write_bvh(tiny_motion(30, 30.0), tmp_path / "walk" / "w1.bvh")
    (tmp_path / "walk" / "bad.bvh").write_text("nonsense")
    table = runner.invoke(app, ["catalog", str(tmp_path)])
    assert table.exit_code == 0
    assert "walk/w1.bvh" in table.output and "1 clips, 1 categories, 30 frames" in table.output
    assert "skipped walk/bad.bvh" in table.output
    js = runner.invoke(app, ["catalog", str(tmp_path), "--json"])
    data = json.loads(js.output)
    assert data["clips"][0]["frames"] == 30 and data["errors"][0]["path"] == "walk/bad.bvh"


def test_catalog_of_missing_folder_is_a_clear_error(tmp_path: Path) -> None:
    r = runner.invoke(app, ["catalog", str(tmp_path / "nope")])
    assert r.exit_code == 2 and "does not exist" in r.output and "Traceback" not in r.output


def test_preview_writes_a_small_gif(tmp_path: Path) -> None:
    write_bvh(tiny_motion(40, 30.0), tmp_path / "w.bvh")
    out = tmp_path / "w.gif"
    r = runner.invoke(app, ["preview", str(tmp_path / "w.bvh"), "--out", str(out), "--max-frames", "10"])
    assert r.exit_code == 0, r.output
    assert out.read_bytes()[:6] in (b"GIF89a", b"GIF87a")
    assert "10 frames of 40" in r.output
    from PIL import Image

    assert Image.open(out).n_frames == 10


def test_preview_of_broken_file_is_a_clear_error(tmp_path: Path) -> None:
    (tmp_path / "b.bvh").write_text("HIERARCHY\n")
    r = runner.invoke(app, ["preview", str(tmp_path / "b.bvh"), "--out", str(tmp_path / "b.gif")])
    assert r.exit_code == 2 and "b.bvh" in r.output



def test_an_unforeseen_failure_is_one_line_not_a_traceback(tmp_path: Path) -> None:
    """The console script's last line of defence (e.g. Prefect's server failing to start)."""
    import subprocess
    import sys

    code = ("import motionweb.flows.commands.cli as c\n"
            "def boom():\n    raise RuntimeError('Timed out while attempting to connect to the server.\\nmore')\n"
            "c.app = boom\nc.main()\n")
    r = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert r.returncode == 1
    assert "Traceback" not in r.stderr
    assert r.stderr.strip().splitlines() == [
        "error: RuntimeError: Timed out while attempting to connect to the server. (MOTIONWEB_DEBUG=1 shows where)"]


def test_retime_a_cmu_jump_in_half_the_time(cmu16: Path, tmp_path: Path, prefect_harness) -> None:
    """``motionweb retime 16_06.amc --duration`` half its length (MPS06 Fig. 1), as a new user runs
    it: the summary gives the flight's ratio, the timing used and that the target was met below
    the shortest timing inside every polygon; the JSON report and the plots are written beside."""
    out = tmp_path / "half.bvh"
    r = runner.invoke(app, ["retime", str(cmu16 / "16_06.amc"), "--out", str(out), "--duration", "1.6917",
                            "--plot", str(tmp_path / "plots")])
    assert r.exit_code == 0, r.output
    assert "Traceback" not in r.output
    assert "16_06: 3.383 s -> 1.692 s" in r.output and "flight 0.417 s" in r.output
    assert "timing (path) met: 1.692 s is shorter than the shortest duration" in r.output
    rep = json.loads(out.with_suffix(".json").read_text())
    assert rep["timing"] == "path" and rep["reachable"]["met"]
    assert len(rep["infeasible_output_frames"]) <= 0.1 * rep["frames_out"]
    assert 0.9 < rep["flights"][0]["ratio"] < 1.1
    assert all(Path(p).stat().st_size > 0 for p in rep["plots"])


def test_retime_a_cmu_walk_with_a_heavier_left_thigh(cmu16: Path, tmp_path: Path, prefect_harness) -> None:
    """``--weight lfemur=10`` (MPS06 Fig. 11): the report records the weight factor beside unchanged
    mass factors and the left single stance lengthens; a malformed factor is one line, exit 2."""
    out = tmp_path / "heavy.bvh"
    r = runner.invoke(app, ["retime", str(cmu16 / "16_16.amc"), "--out", str(out), "--duration", "4",
                            "--weight", "lfemur=heavy"])
    assert r.exit_code == 2 and "--weight 'lfemur=heavy': expected JOINT=FACTOR" in r.output, r.output
    assert "Traceback" not in r.output and not out.exists()
    r = runner.invoke(app, ["retime", str(cmu16 / "16_16.amc"), "--out", str(out), "--duration", "4.2417",
                            "--weight", "lfemur=10"])
    assert r.exit_code == 0, r.output
    rep = json.loads(out.with_suffix(".json").read_text())
    assert rep["weight_factors"]["lfemur"] == 10.0 and set(rep["mass_factors"].values()) == {1.0}
    left = rep["phase_seconds"]["lfoot only"]
    assert left["output"] > 1.05 * left["source"]


def test_a_request_refused_inside_the_flow_is_one_line(tmp_path: Path) -> None:
    """``retime`` of a BVH that declares no length unit (the physics needs metres): the error is
    raised inside the flow run, where Prefect's task log would print its traceback first; the
    user sees one line naming the file, exit 2."""
    import os
    import subprocess
    import sys

    write_bvh(tiny_motion(40, 30.0), tmp_path / "tiny.bvh")
    env = {k: v for k, v in os.environ.items() if not k.startswith("PREFECT_API")}
    env["PREFECT_HOME"] = str(tmp_path / "prefect")
    r = subprocess.run([sys.executable, "-m", "motionweb.flows.commands.cli", "retime", "tiny.bvh", "--out", "r.bvh",
                        "--duration", "1"], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 2, (r.stdout, r.stderr)
    assert "Traceback" not in r.stdout + r.stderr, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "tiny.bvh" in lines[0] and "length unit" in lines[0], lines
