"""FBX export through Blender (issue 26, design §11).

Autodesk's FBX SDK is not needed: the motion is written as GLB (:mod:`store.gltf`), then Blender's
own glTF importer and FBX exporter convert it, in a subprocess running Blender as a Python module
(the ``bpy`` wheel). A subprocess because bpy holds one global scene per process, is large to
import, and a crash in it must not take the caller down.

The scene's frame rate is set to the clip's before the import (``fps`` = round(clip fps) over
``fps_base``; the tests check 30 and 120 fps, a fractional rate is untested), the animation is baked at
every frame without simplification, and leaf bones are not added, so the FBX has one bone per
joint with the joint's name. Cost of the extra: the bpy wheel is ~375 MB (bpy 5.0.1,
manylinux x86-64, ~1 GB installed) and is built for one CPython version (bpy 5.0.1: 3.11 only)
and pins numpy < 2 (bpy 5.0.1: ``numpy<2.0,>=1.26``), while motionweb needs
numpy >= 2: the two cannot share an environment, so there is no ``motionweb[blender]`` extra.
Blender runs from an interpreter of its own, named by ``$MOTIONWEB_BLENDER_PYTHON`` (or this
interpreter, where bpy imports here); :func:`write_fbx` says how to set one up where none is found.
"""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from motionweb.store.gltf import write_glb
from motionweb.store.motion import Motion

#: seconds a conversion may take (Blender starts in ~2 s; a long clip bakes in seconds)
TIMEOUT_S = 600

BLENDER_ENV = "MOTIONWEB_BLENDER_PYTHON"
INSTALL_HINT = ("FBX export runs Blender as a Python module in an interpreter of its own (bpy needs numpy < 2, "
                "CPython 3.11, a ~375 MB wheel): python3.11 -m venv blender-venv && blender-venv/bin/pip install bpy, "
                f"then set {BLENDER_ENV}=blender-venv/bin/python")

#: run by the subprocess: argv = glb, fbx, fps
_SCRIPT = r"""
import sys
import bpy

glb, fbx, fps = sys.argv[1], sys.argv[2], float(sys.argv[3])
bpy.ops.wm.read_factory_settings(use_empty=True)
scene = bpy.context.scene
scene.render.fps = max(1, round(fps))
scene.render.fps_base = scene.render.fps / fps
bpy.ops.import_scene.gltf(filepath=glb)
starts, ends = [], []
for action in bpy.data.actions:
    starts.append(action.frame_range[0])
    ends.append(action.frame_range[1])
if starts:
    scene.frame_start = int(round(min(starts)))
    scene.frame_end = int(round(max(ends)))
bpy.ops.export_scene.fbx(filepath=fbx, object_types={"ARMATURE", "MESH"}, add_leaf_bones=False,
                         bake_anim=True, bake_anim_use_all_actions=False, bake_anim_use_nla_strips=False,
                         bake_anim_force_startend_keying=True, bake_anim_step=1.0, bake_anim_simplify_factor=0.0,
                         axis_forward="-Z", axis_up="Y")
"""


def blender_python() -> str | None:
    """The interpreter that runs Blender: ``$MOTIONWEB_BLENDER_PYTHON`` when set to a file, else
    this one when bpy imports here, else None."""
    env = os.environ.get(BLENDER_ENV)
    if env:
        return env if Path(env).is_file() else None
    return sys.executable if importlib.util.find_spec("bpy") is not None else None


def write_fbx(motion: Motion, path: str | Path, up: str = "y") -> None:
    """Write a motion as FBX through Blender (see the module's docstring). ValueError naming the
    file when bpy is missing, the unit is unknown, or Blender fails (its last lines quoted)."""
    path = Path(path)
    python = blender_python()
    if python is None:
        where = f" ({BLENDER_ENV}={os.environ[BLENDER_ENV]} is not a file)" if os.environ.get(BLENDER_ENV) else ""
        raise ValueError(f"cannot write {path}: {INSTALL_HINT}{where}")
    with tempfile.TemporaryDirectory(prefix="motionweb-fbx-") as tmp:
        glb = Path(tmp) / "motion.glb"
        write_glb(motion, glb, up=up)
        run = subprocess.run([python, "-c", _SCRIPT, str(glb), str(path.resolve()), repr(float(motion.fps))],
                             capture_output=True, text=True, timeout=TIMEOUT_S, check=False)
    if run.returncode != 0 or not path.is_file():
        tail = " | ".join((run.stderr or run.stdout).strip().splitlines()[-3:])
        raise ValueError(f"cannot write {path}: Blender's FBX conversion failed (exit {run.returncode}): {tail}")
