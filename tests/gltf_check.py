"""Test helpers for GLB files (imported by module name: ``from gltf_check import ...``).

* :func:`glb_world_positions` reads a GLB with pygltflib and composes the nodes' TRS along the
  file's own node hierarchy in numpy, at every key time of its animation: the joint world
  positions a viewer would show, computed without motionweb's FK.
* :func:`validate` runs the Khronos glTF validator (npm package ``gltf-validator``) under node.
  It is looked for in ``$MOTIONWEB_GLTF_VALIDATOR`` (the package folder) or in
  ``<checkout>/.cache/npm/node_modules/gltf-validator``, where ``.ci/run`` installs it
  (``npm install --prefix .cache/npm gltf-validator``); tests skip with the reason when node or
  the package is absent.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pygltflib as gl
import pytest

VALIDATOR_ENV = "MOTIONWEB_GLTF_VALIDATOR"
VALIDATOR_DIR = Path(__file__).resolve().parents[1] / ".cache" / "npm" / "node_modules" / "gltf-validator"

_COMPONENTS = {gl.FLOAT: np.float32, gl.UNSIGNED_SHORT: np.uint16, gl.UNSIGNED_INT: np.uint32,
               gl.UNSIGNED_BYTE: np.uint8}
_WIDTH = {gl.SCALAR: 1, gl.VEC2: 2, gl.VEC3: 3, gl.VEC4: 4, gl.MAT4: 16}


def accessor(doc: gl.GLTF2, blob: bytes, k: int) -> np.ndarray:
    """Accessor ``k`` as a (count, width) array (tightly packed views only, as motionweb writes)."""
    acc = doc.accessors[k]
    view = doc.bufferViews[acc.bufferView]
    dtype = np.dtype(_COMPONENTS[acc.componentType])
    start = (view.byteOffset or 0) + (acc.byteOffset or 0)
    n = acc.count * _WIDTH[acc.type]
    return np.frombuffer(blob, dtype, n, start).reshape(acc.count, _WIDTH[acc.type])


def _quat_matrix(xyzw: np.ndarray) -> np.ndarray:
    x, y, z, w = np.moveaxis(xyzw / np.linalg.norm(xyzw, axis=-1, keepdims=True), -1, 0)
    return np.stack([np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
                     np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
                     np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], -2)


def glb_world_positions(path: Path) -> tuple[np.ndarray, list[str], np.ndarray, gl.GLTF2]:
    """World positions (F, J, 3) of the skin's joints at the animation's key times, the joints'
    names, the key times (F,), and the document. Every node's local matrix is T·R·S from its
    animated (or static) TRS; world = parent world · local, following ``children``."""
    doc = gl.GLTF2().load_binary(str(path))
    blob = doc.binary_blob()
    anim = doc.animations[0]
    times = accessor(doc, blob, anim.samplers[0].input)[:, 0].astype(np.float64)
    f, n = len(times), len(doc.nodes)
    trans = np.array([nd.translation or [0.0, 0.0, 0.0] for nd in doc.nodes], np.float64)[None].repeat(f, 0)
    rot = np.array([nd.rotation or [0.0, 0.0, 0.0, 1.0] for nd in doc.nodes], np.float64)[None].repeat(f, 0)
    scale = np.array([nd.scale or [1.0, 1.0, 1.0] for nd in doc.nodes], np.float64)
    for ch in anim.channels:
        s = anim.samplers[ch.sampler]
        assert np.array_equal(accessor(doc, blob, s.input)[:, 0], times.astype(np.float32))
        values = accessor(doc, blob, s.output).astype(np.float64)
        {"translation": trans, "rotation": rot}[ch.target.path][:, ch.target.node] = values
    local = np.zeros((f, n, 4, 4))
    local[..., :3, :3] = _quat_matrix(rot) * scale[None, :, None, :]
    local[..., :3, 3] = trans
    local[..., 3, 3] = 1.0
    world = np.full((f, n, 4, 4), np.nan)
    parent = {c: p for p, nd in enumerate(doc.nodes) for c in (nd.children or [])}

    def solve(k: int) -> np.ndarray:
        if np.isnan(world[0, k, 3, 3]):
            world[:, k] = local[:, k] if k not in parent else solve(parent[k]) @ local[:, k]
        return world[:, k]

    joints = doc.skins[0].joints
    pos = np.stack([solve(k)[:, :3, 3] for k in joints], axis=1)
    return pos, [doc.nodes[k].name for k in joints], times, doc


def validator_or_skip() -> Path:
    """The gltf-validator package folder, or skip with the reason."""
    if shutil.which("node") is None:
        pytest.skip("node is not installed: the Khronos glTF validator (npm gltf-validator) runs under node")
    d = Path(os.environ.get(VALIDATOR_ENV) or VALIDATOR_DIR)
    if not (d / "package.json").is_file():
        pytest.skip(f"npm package gltf-validator not found at {d} (.ci/run installs it: "
                    f"npm install --prefix .cache/npm gltf-validator; or set {VALIDATOR_ENV})")
    return d


_SCRIPT = """
const v = require(process.argv[1]);
const fs = require('fs');
(async () => {
  const out = [];
  for (const f of process.argv.slice(2)) {
    const r = await v.validateBytes(new Uint8Array(fs.readFileSync(f)), {maxIssues: 100});
    out.push({file: f, errors: r.issues.numErrors, warnings: r.issues.numWarnings,
              messages: r.issues.messages.filter(m => m.severity <= 1).map(m => m.code + ' ' + (m.pointer || '') + ': ' + m.message)});
  }
  console.log(JSON.stringify(out));
})().catch(e => { console.error(String(e)); process.exit(1); });
"""


def validate(paths: list[Path]) -> list[dict]:
    """The validator's report of each file: ``{file, errors, warnings, messages}``."""
    d = validator_or_skip()
    run = subprocess.run(["node", "-e", _SCRIPT, str(d), *map(str, paths)], check=False, capture_output=True,
                         text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    return json.loads(run.stdout)
