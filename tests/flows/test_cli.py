"""The motionweb CLI: help on every command, catalog table/JSON, preview GIF, clear errors."""

from __future__ import annotations

import json
from pathlib import Path

from fixtures import tiny_motion
from motionweb.flows.cli import app
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

    code = ("import motionweb.flows.cli as c\n"
            "def boom():\n    raise RuntimeError('Timed out while attempting to connect to the server.\\nmore')\n"
            "c.app = boom\nc.main()\n")
    r = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert r.returncode == 1
    assert "Traceback" not in r.stderr
    assert r.stderr.strip().splitlines() == [
        "error: RuntimeError: Timed out while attempting to connect to the server. (MOTIONWEB_DEBUG=1 shows where)"]
