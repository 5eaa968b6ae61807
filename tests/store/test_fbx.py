"""FBX through Blender (store/fbx.py, issue 26): the joint world positions Blender reads back from
the written FBX equal motionweb's FK within 1e-4 m at every frame. Marked ``blender``: runs where
an interpreter with bpy is found ($MOTIONWEB_BLENDER_PYTHON, or <checkout>/.cache/blender-venv, made
by ``python3.11 -m venv .cache/blender-venv && .cache/blender-venv/bin/pip install bpy``), skips
otherwise; the error without Blender always runs."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
from fixtures import wiggle
from motionweb.store.fbx import BLENDER_ENV, blender_python, write_fbx
from motionweb.store.formats import read_motion, write_motion
from motionweb.store.kinematics import forward_kinematics
from motionweb.store.motion import Motion

VENV_PYTHON = Path(__file__).resolve().parents[2] / ".cache" / "blender-venv" / "bin" / "python"

#: run by Blender's interpreter: import the FBX, world positions of every bone head per frame
READ_BACK = r"""
import json, sys
import bpy
import numpy as np
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.import_scene.fbx(filepath=sys.argv[1])
scene = bpy.context.scene
arm = [o for o in scene.objects if o.type == "ARMATURE"][0]
f0, f1 = (int(round(f)) for f in arm.animation_data.action.frame_range)
pos = []
for f in range(f0, f1 + 1):
    scene.frame_set(f)
    pos.append([list(arm.matrix_world @ pb.head) for pb in arm.pose.bones])
np.save(sys.argv[2], np.array(pos))
print(json.dumps({"names": [pb.name for pb in arm.pose.bones], "fps": scene.render.fps / scene.render.fps_base}))
"""


@pytest.fixture
def blender(monkeypatch: pytest.MonkeyPatch) -> str:
    if blender_python() is None and VENV_PYTHON.is_file():
        monkeypatch.setenv(BLENDER_ENV, str(VENV_PYTHON))
    python = blender_python()
    if python is None:
        pytest.skip(f"no Python with Blender's bpy: set {BLENDER_ENV} or make {VENV_PYTHON.parent.parent} "
                    "(bpy needs numpy < 2 and CPython 3.11, so it lives apart from motionweb)")
    return python


def check(python: str, m: Motion, path: Path) -> None:
    write_motion(m, path)
    run = subprocess.run([python, "-c", READ_BACK, str(path), str(path.with_suffix(".npy"))],
                         capture_output=True, text=True, timeout=600, check=False)
    assert run.returncode == 0, run.stderr[-2000:]
    info = json.loads(run.stdout.strip().splitlines()[-1])
    assert info["fps"] == pytest.approx(m.fps)
    blender_zup = np.load(path.with_suffix(".npy"))
    got = np.stack([blender_zup[..., 0], blender_zup[..., 2], -blender_zup[..., 1]], -1)  # Blender is Z up
    order = [info["names"].index(n) for n in m.skeleton.names]
    want = forward_kinematics(m)[0] * m.metres()
    assert got.shape[0] == m.n_frames
    np.testing.assert_allclose(got[:, order], want, atol=1e-4)


@pytest.mark.blender
def test_synthetic_fbx_round_trip(blender: str, tmp_path: Path) -> None:
    check(blender, wiggle(45, 30.0, seed=11, unit="cm"), tmp_path / "w.fbx")


@pytest.mark.blender
@pytest.mark.slow
def test_cmu_fbx_round_trip(blender: str, cmu16: Path, tmp_path: Path) -> None:
    check(blender, read_motion(cmu16 / "16_15.amc"), tmp_path / "walk.fbx")


def test_without_blender_the_error_says_how(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv(BLENDER_ENV, str(tmp_path / "no-python"))
    with pytest.raises(ValueError, match=r"cannot write .*x\.fbx: .*pip install bpy.*no-python is not a file"):
        write_fbx(wiggle(5, 30.0, seed=1), tmp_path / "x.fbx")
