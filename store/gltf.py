"""glTF 2.0 binary (GLB) export of a motion (issue 26; design "Exports").

What a written file holds (glTF 2.0 specification, §3.7 skins, §3.11 animations, §4.4 GLB):

* one node per joint, parents before children, each with its rest offset as translation (metres,
  Y up) and the clip's first pose as rotation; the root node also carries the root position;
* a skin over those nodes (``skeleton`` = the root) whose inverse bind matrices are those of the
  rest pose (every local rotation the identity, the root at its rest offset): in every skeleton
  motionweb reads, joint frames are aligned with the global axes at rest, so a bind matrix is a
  translation and its inverse one too;
* a mesh with one box per bone (parent joint to child joint, and joint to end site), each box
  skinned rigidly (weight 1) to the joint that moves it, so any viewer shows a figure;
* one animation at the clip's frame rate (input = frame times ``arange(F) / fps``, LINEAR):
  a rotation sampler per joint, quaternions (x, y, z, w) as glTF orders them (motionweb stores
  (w, x, y, z), (F, J, 4)), kept on one hemisphere frame to frame so LINEAR slerp follows the
  clip; a translation sampler for the root and for every joint with position channels.

Units and axes: lengths are multiplied by :meth:`Motion.metres` (a motion without a known length
unit cannot be exported: the error says how to declare it). The vertical axis of the motion is a
setting (``up``, the config's ``corpus.up_axis``); glTF is Y up, so a Z-up or X-up motion is
turned by the proper rotation ``r`` taking that axis onto +Y (Z up: −90° about X), applied to
offsets, translations and, by conjugation ``r q r⁻¹``, to every local rotation: world positions
become ``r p`` and handedness is kept.

Library: pygltflib (MIT) — a maintained, typed dataclass model of the whole glTF 2.0 schema that
packs and parses GLB containers (header, JSON chunk, 4-byte aligned BIN chunk), so this module
only lays out arrays; hand-written JSON would repeat that schema with no checks. Every file the
tests write passes the Khronos glTF validator with 0 errors (tests/store/test_gltf.py).

Cost: O(F·J) to lay out the samplers, plus 24 vertices per bone.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pygltflib as gl
from motionweb.store.kinematics import axis_index, quat_from_axis_angle, quat_inv, quat_mul, quat_rotate
from motionweb.store.motion import Motion

#: box cross-section (m): this fraction of the bone's length, clamped to [BOX_MIN, BOX_MAX]
BOX_FRACTION, BOX_MIN, BOX_MAX = 0.18, 0.012, 0.05
#: the figure's colour (linear RGBA)
FIGURE_RGBA = [0.72, 0.74, 0.78, 1.0]


def up_to_y(up: str = "y") -> np.ndarray:
    """The rotation (4,) (w, x, y, z) taking the motion's ``up`` axis onto glTF's +Y: the identity
    for Y, −90° about X for Z ((x, y, z) → (x, z, −y)), +90° about Z for X."""
    k = axis_index(up)
    if k == 1:
        return np.array([1.0, 0.0, 0.0, 0.0])
    axis = np.array([1.0, 0.0, 0.0]) if k == 2 else np.array([0.0, 0.0, 1.0])
    return quat_from_axis_angle(axis, -np.pi / 2 if k == 2 else np.pi / 2)


def gltf_pose(motion: Motion, up: str = "y") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The motion in glTF's frame: local translations (F, J, 3) in metres, local rotations
    (F, J, 4) (w, x, y, z) made continuous in time (q and −q chosen per frame so consecutive
    quaternions have a non-negative dot product), and rest offsets (J, 3) in metres, all turned
    from ``up`` to Y (see the module's docstring)."""
    s = motion.metres()
    r = up_to_y(up)
    ri = quat_inv(r)
    trans = quat_rotate(r, motion.local_translations() * s)
    rot = quat_mul(quat_mul(r, motion.rotations), ri)
    rot = rot / np.linalg.norm(rot, axis=-1, keepdims=True)
    if len(rot) > 1:
        flip = np.sum(rot[1:] * rot[:-1], axis=-1) < 0
        sign = np.concatenate([np.ones((1,) + flip.shape[1:]), np.where(np.cumsum(flip, axis=0) % 2, -1.0, 1.0)])
        rot = rot * sign[..., None]
    rest = quat_rotate(r, motion.skeleton.offsets * s)
    return trans, rot, rest


def _bind_positions(parents: np.ndarray, rest: np.ndarray) -> np.ndarray:
    """(J, 3) joint positions in the rest pose (identity rotations, root at its rest offset)."""
    pos = np.zeros_like(rest)
    for j in range(len(parents)):
        pos[j] = rest[j] if parents[j] < 0 else pos[parents[j]] + rest[j]
    return pos


def _box(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A box from point a to point b: 24 vertices (4 per face, so faces have flat normals),
    their unit normals (24, 3) and 12 triangles (12, 3) wound counter-clockwise seen from outside."""
    d = b - a
    length = float(np.linalg.norm(d))
    ax = d / length
    half = 0.5 * float(np.clip(BOX_FRACTION * length, BOX_MIN, BOX_MAX))
    helper = np.array([0.0, 1.0, 0.0]) if abs(ax[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    u = np.cross(ax, helper)
    u /= np.linalg.norm(u)
    v = np.cross(ax, u)  # (u, v, ax) is right-handed
    corners = np.array([[i, j, k] for k in (0, 1) for j in (-1, 1) for i in (-1, 1)], dtype=np.float64)
    pts = a + corners[:, :1] * half * u + corners[:, 1:2] * half * v + corners[:, 2:] * d
    # faces as corner indices, counter-clockwise seen from outside, with their outward normals
    faces = [((0, 2, 3, 1), -ax), ((4, 5, 7, 6), ax), ((0, 1, 5, 4), -v),
             ((2, 6, 7, 3), v), ((0, 4, 6, 2), -u), ((1, 3, 7, 5), u)]
    verts, normals, tris = [], [], []
    for f, (quad, n) in enumerate(faces):
        verts.extend(pts[list(quad)])
        normals.extend([n] * 4)
        o = 4 * f
        tris += [(o, o + 1, o + 2), (o, o + 2, o + 3)]
    return np.array(verts), np.array(normals), np.array(tris)


class _Blob:
    """The BIN chunk being laid out: buffer views 4-byte aligned, one accessor each."""

    def __init__(self) -> None:
        self.parts: list[bytes] = []
        self.size = 0
        self.views: list[gl.BufferView] = []
        self.accessors: list[gl.Accessor] = []

    def add(self, data: np.ndarray, kind: str, component: int, target: int | None = None,
            minmax: bool = False) -> int:
        raw = np.ascontiguousarray(data).tobytes()
        self.views.append(gl.BufferView(buffer=0, byteOffset=self.size, byteLength=len(raw), target=target))
        pad = (-len(raw)) % 4
        self.parts.append(raw + b"\0" * pad)
        self.size += len(raw) + pad
        count = len(data)
        acc = gl.Accessor(bufferView=len(self.views) - 1, componentType=component, count=count, type=kind)
        if minmax:
            flat = np.asarray(data, np.float64).reshape(count, -1)
            acc.min = [float(x) for x in flat.min(axis=0)]
            acc.max = [float(x) for x in flat.max(axis=0)]
        self.accessors.append(acc)
        return len(self.accessors) - 1

    def bytes(self) -> bytes:
        return b"".join(self.parts)


def glb_document(motion: Motion, up: str = "y") -> gl.GLTF2:
    """The glTF document of a motion (see the module's docstring), its BIN chunk set."""
    sk = motion.skeleton
    n_j, f = sk.n_joints, motion.n_frames
    trans, rot, rest = gltf_pose(motion, up)
    bind = _bind_positions(sk.parents, rest)
    blob = _Blob()

    # mesh: boxes in bind space, each skinned to one joint
    s = motion.metres()
    r = up_to_y(up)
    verts, normals, vjoint, tris = _figure(motion, bind, rest, s, r)
    pos_acc = blob.add(verts.astype(np.float32), gl.VEC3, gl.FLOAT, gl.ARRAY_BUFFER, minmax=True)
    nrm_acc = blob.add(normals.astype(np.float32), gl.VEC3, gl.FLOAT, gl.ARRAY_BUFFER)
    joints4 = np.zeros((len(verts), 4), np.uint16)
    joints4[:, 0] = vjoint
    weights4 = np.zeros((len(verts), 4), np.float32)
    weights4[:, 0] = 1.0
    jnt_acc = blob.add(joints4, gl.VEC4, gl.UNSIGNED_SHORT, gl.ARRAY_BUFFER)
    wgt_acc = blob.add(weights4, gl.VEC4, gl.FLOAT, gl.ARRAY_BUFFER)
    idx_acc = blob.add(tris.reshape(-1).astype(np.uint32), gl.SCALAR, gl.UNSIGNED_INT, gl.ELEMENT_ARRAY_BUFFER)

    # skin: inverse bind matrices of the rest pose (translations), column-major
    ibm = np.tile(np.eye(4), (n_j, 1, 1))
    ibm[:, :3, 3] = -bind
    ibm_acc = blob.add(np.transpose(ibm, (0, 2, 1)).reshape(n_j, 16).astype(np.float32), gl.MAT4, gl.FLOAT)

    # animation: one time accessor shared by every sampler
    times = (np.arange(f) / motion.fps).astype(np.float32)
    t_acc = blob.add(times, gl.SCALAR, gl.FLOAT, minmax=True)
    samplers: list[gl.AnimationSampler] = []
    channels: list[gl.AnimationChannel] = []

    def track(node: int, path: str, values: np.ndarray, kind: str) -> None:
        out = blob.add(values.astype(np.float32), kind, gl.FLOAT)
        samplers.append(gl.AnimationSampler(input=t_acc, output=out, interpolation=gl.ANIM_LINEAR))
        channels.append(gl.AnimationChannel(sampler=len(samplers) - 1,
                                            target=gl.AnimationChannelTarget(node=node, path=path)))

    moving = {0} | set(motion.translations)
    for j in range(n_j):
        if j in moving:
            track(j, "translation", trans[:, j], gl.VEC3)
        track(j, "rotation", rot[:, j][:, [1, 2, 3, 0]], gl.VEC4)

    nodes = []
    for j in range(n_j):
        t0 = trans[0, j] if j in moving else rest[j]
        q0 = rot[0, j]
        nodes.append(gl.Node(name=sk.names[j], children=sk.children(j) or [],
                             translation=[float(x) for x in t0],
                             rotation=[float(q0[1]), float(q0[2]), float(q0[3]), float(q0[0])]))
    mesh_node = n_j
    nodes.append(gl.Node(name=f"{motion.name or 'motion'}_figure", mesh=0, skin=0))
    doc = gl.GLTF2(
        asset=gl.Asset(version="2.0", generator="motionweb (store/gltf.py, pygltflib)"),
        scene=0,
        scenes=[gl.Scene(name=motion.name or "motion", nodes=[0, mesh_node])],
        nodes=nodes,
        meshes=[gl.Mesh(name="figure", primitives=[gl.Primitive(
            attributes=gl.Attributes(POSITION=pos_acc, NORMAL=nrm_acc, JOINTS_0=jnt_acc, WEIGHTS_0=wgt_acc),
            indices=idx_acc, material=0, mode=gl.TRIANGLES)])],
        materials=[gl.Material(name="figure", pbrMetallicRoughness=gl.PbrMetallicRoughness(
            baseColorFactor=FIGURE_RGBA, metallicFactor=0.0, roughnessFactor=0.8))],
        skins=[gl.Skin(name="skeleton", joints=list(range(n_j)), skeleton=0, inverseBindMatrices=ibm_acc)],
        animations=[gl.Animation(name=motion.name or "motion", samplers=samplers, channels=channels)],
        accessors=blob.accessors,
        bufferViews=blob.views,
        buffers=[gl.Buffer(byteLength=blob.size)],
    )
    doc.set_binary_blob(blob.bytes())
    return doc


def _figure(motion: Motion, bind: np.ndarray, rest: np.ndarray, scale: float, r: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`figure_mesh` of a motion, end sites in metres, turned to Y up by ``r``."""
    sk = motion.skeleton
    ends = {j: quat_rotate(r, off * scale) for j, off in sk.end_sites.items()}
    return figure_mesh(sk.parents, bind, rest, ends)


def figure_mesh(parents: np.ndarray, bind: np.ndarray, rest: np.ndarray, ends: dict[int, np.ndarray]
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Boxes of the rest figure: positions (V, 3) and normals (V, 3) in metres (bind space),
    the joint (V,) each vertex is skinned to, and triangles (T, 3). A bone is a segment from a
    joint to a child with a non-zero rest offset ``rest`` (J, 3) (skinned to the joint), or to an
    end site (``ends``: joint → (3,) offset, metres); ``bind`` (J, 3) are the rest positions. A
    skeleton without any bone gets a small box at its root."""
    segs: list[tuple[int, np.ndarray, np.ndarray]] = []
    for j in range(1, len(parents)):
        if np.linalg.norm(rest[j]) > 1e-6:
            p = int(parents[j])
            segs.append((p, bind[p], bind[j]))
    for j, e in sorted(ends.items()):
        if np.linalg.norm(e) > 1e-6:
            segs.append((j, bind[j], bind[j] + e))
    if not segs:
        segs.append((0, bind[0] - [0, BOX_MIN, 0], bind[0] + [0, BOX_MIN, 0]))
    verts, normals, joints, tris = [], [], [], []
    offset = 0
    for j, a, b in segs:
        v, n, t = _box(np.asarray(a, float), np.asarray(b, float))
        tris.append(t + offset)
        offset += len(v)
        verts.append(v)
        normals.append(n)
        joints.append(np.full(len(v), j))
    return np.concatenate(verts), np.concatenate(normals), np.concatenate(joints), np.concatenate(tris)


def glb_bytes(motion: Motion, up: str = "y") -> bytes:
    """The GLB file of a motion (header, JSON chunk, BIN chunk) as bytes."""
    return b"".join(glb_document(motion, up).save_to_bytes())


def write_glb(motion: Motion, path: str | Path, up: str = "y") -> None:
    """Write a motion as a GLB file (see the module's docstring). ValueError naming the file
    when the motion's length unit is unknown (glTF is in metres)."""
    path = Path(path)
    try:
        data = glb_bytes(motion, up)
    except ValueError as exc:
        raise ValueError(f"cannot write {path}: {exc}") from None
    path.write_bytes(data)
