"""``motionweb export``, ``mirror`` and ``cleanup`` (flows/commands/export_cli.py, issue 26): GLB or BVH by
suffix or --format, root motion in place, one-line errors; the GLB files pass the validator."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from gltf_check import glb_world_positions, validate
from motionweb.flows.commands.cli import app
from motionweb.store.bvh import write_bvh
from motionweb.store.demo.corpus import generate_clip
from motionweb.store.formats import read_motion
from motionweb.store.kinematics import forward_kinematics
from typer.testing import CliRunner

runner = CliRunner()


@pytest.fixture
def clip(tmp_path: Path) -> tuple[Path, Path]:
    """A demo walk as BVH (no unit in the file) and a config declaring metres."""
    walk, _ = generate_clip("walk", 0, 7, 30.0)
    write_bvh(walk, tmp_path / "walk.bvh")
    cfg = tmp_path / "config.yaml"
    cfg.write_text(f"corpus:\n  length_unit: m\noutput: {tmp_path / 'out'}\n")
    return tmp_path / "walk.bvh", cfg


def run(*args: str) -> str:
    r = runner.invoke(app, [str(a) for a in args])
    assert r.exit_code == 0, r.output
    return r.output


def test_export_mirror_cleanup_write_glb_and_bvh(clip: tuple[Path, Path], tmp_path: Path) -> None:
    bvh, cfg = clip
    m = read_motion(bvh, unit="m")
    out = run("export", bvh, "--out", tmp_path / "w.glb", "--config", cfg)
    assert f"(GLB): {m.n_frames} frames at 30 fps" in out
    np.testing.assert_allclose(glb_world_positions(tmp_path / "w.glb")[0], forward_kinematics(m)[0], atol=1e-4)
    out = run("export", bvh, "--out", tmp_path / "rm.glb", "--root-motion", "in-place", "--config", cfg)
    assert "root motion on its own joint" in out
    pos, names, _, _ = glb_world_positions(tmp_path / "rm.glb")
    assert names[:2] == ["root", "Hips"]
    np.testing.assert_allclose(pos[:, 1:], forward_kinematics(m)[0], atol=1e-4)
    out = run("mirror", bvh, "--out", tmp_path / "mirror.glb", "--config", cfg)
    assert "8 left/right pairs, plane normal x" in out
    out = run("mirror", bvh, "--out", tmp_path / "mirror.txt", "--format", "bvh", "--config", cfg)
    assert (tmp_path / "mirror.txt").read_text().startswith("HIERARCHY")
    out = run("cleanup", bvh, "--out", tmp_path / "clean.glb", "--config", cfg)
    assert "foot skate" in out and "cm/s" in out
    for rep in validate([tmp_path / n for n in ("w.glb", "rm.glb", "mirror.glb", "clean.glb")]):
        assert rep["errors"] == 0, rep


def test_clear_errors(clip: tuple[Path, Path], tmp_path: Path) -> None:
    bvh, cfg = clip
    bare = tmp_path / "bare.yaml"
    bare.write_text(f"output: {tmp_path / 'out'}\n")
    cases = [
        (["export", bvh, "--out", tmp_path / "x.obj", "--config", cfg], "x.obj: cannot tell the motion format"),
        (["export", bvh, "--out", tmp_path / "x.glb", "--config", bare], "length unit is not declared"),
        (["export", tmp_path / "nope.bvh", "--out", tmp_path / "x.glb", "--config", cfg], "nope.bvh: no such file"),
        (["cleanup", bvh, "--out", tmp_path / "x.glb", "--config", cfg, "--format", "obj"], "Invalid value"),
    ]
    for args, text in cases:
        r = runner.invoke(app, [str(a) for a in args])
        assert r.exit_code == 2, (args, r.output)
        assert text in r.output and "Traceback" not in r.output, r.output


def test_warp_writes_glb_by_suffix(clip: tuple[Path, Path], tmp_path: Path) -> None:
    """A command that writes a motion (here `warp`) writes GLB when --out ends in .glb."""
    bvh, cfg = clip
    r = runner.invoke(app, ["warp", str(bvh), "--duration", "3.0", "--out", str(tmp_path / "w.glb"), "--config", str(cfg)])
    assert r.exit_code == 0, r.output
    pos, names, times, _ = glb_world_positions(tmp_path / "w.glb")
    assert names == list(read_motion(bvh, unit="m").skeleton.names)
    assert times[-1] == pytest.approx(3.0, abs=1 / 30) and np.isfinite(pos).all()
    for rep in validate([tmp_path / "w.glb"]):
        assert rep["errors"] == 0, rep


def test_search_exports_and_registers_glb(app_store: Path, tmp_path: Path) -> None:
    """``motionweb search --format glb``: the exported matches and the registered examples are GLB
    files (the validator passes them) whose joints follow the indexed clips' FK."""
    r = runner.invoke(app, ["search", str(app_store), "--clip", "walk_00", "--start", "1.0", "--end", "2.5",
                            "--quantile", "0.8", "--register", "--export", str(tmp_path / "x"),
                            "--out", str(tmp_path / "o"), "--format", "glb"])
    assert r.exit_code == 0, r.output
    exported = sorted((tmp_path / "x").glob("*.glb"))
    registered = sorted((tmp_path / "o" / "registered").glob("*.glb"))
    assert exported and registered and not list((tmp_path / "x").glob("*.bvh"))
    query = exported[0]  # rank 000: the query itself, walk_00 frames at the web rate
    pos, _, times, _ = glb_world_positions(query)
    assert np.isfinite(pos).all() and times[-1] > 1.0
    for rep in validate(exported + registered):
        assert rep["errors"] == 0, rep
    bad = runner.invoke(app, ["search", str(app_store), "--clip", "walk_00", "--start", "1.0", "--end", "2.5",
                              "--format", "obj"])
    assert bad.exit_code == 2 and "format: Input should be 'bvh' or 'glb'" in bad.output
