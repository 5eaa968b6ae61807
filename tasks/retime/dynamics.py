"""Body model and path dynamics for physics-based retiming (design §8, MPS06 §3.1).

A motion q(s) played back with a timing p(t) has velocity q̇ = q' ṗ and acceleration
q̈ = q'' ṗ² + q' p̈ (MPS06 Eqn. 3-4), so the generalized forces it needs are (Eqn. 5-6)

    τ = a(s) p̈ + b(s) ṗ² + c(s),   a = M q',  b = M q'' + C(q, q') q',  c = gravity term.

Inverse dynamics is linear in each body's inertial parameters and in the gravity vector, so we
store every term split by body (and ``c`` split by gravity axis): a new gravity vector or a limb
mass multiplier recombines stored terms without running the dynamics again (the role of the
polynomial-typed Featherstone code of MPS06 §3.1). Per-body terms come from Pinocchio's joint
torque regressor Y(q, v, a) (τ = Y π), contracted with each body's 10 dynamic parameters π_b.

Cost: five regressor calls per frame, O(F · nv · n_bodies) each; storage O(F · nv · n_bodies).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pinocchio as pin
from motionweb.store.motion import Motion, Skeleton

WATER_DENSITY = 1000.0  # kg / m^3
DEFAULT_RADIUS_RATIO = 0.15  # cylinder radius / bone length
LEAF_SPHERE_RADIUS = 0.04  # m, for leaf joints with no bone
GRAVITY = 9.81

#: Segment mass fractions (Winter, Biomechanics and Motor Control of Human Movement, Table 4.1),
#: matched to joint names by keyword; joints that match nothing share the rest by bone volume.
ANTHROPOMETRIC_TABLE: tuple[tuple[tuple[str, ...], float], ...] = (
    (("head", "neck"), 0.081),
    (("hand", "wrist"), 0.006),
    (("forearm", "elbow", "lowerarm"), 0.016),
    (("upperarm", "shoulder", "arm"), 0.028),
    (("foot", "ankle", "toe"), 0.0145),
    (("shin", "knee", "leg", "calf", "lowerleg"), 0.0465),
    (("thigh", "upleg", "hip", "femur", "upperleg"), 0.100),
)


@dataclass(frozen=True, eq=False)
class BodyModel:
    """A rigid-body model of a skeleton, in metres and kilograms.

    Pinocchio joint ``j + 1`` is skeleton joint ``j`` (0 is Pinocchio's universe): a free-flyer
    for the root and a spherical joint for every other joint; body ``j`` is attached to joint
    ``j + 1``. Configurations follow Pinocchio (root position, then (x, y, z, w) quaternions).

    Attributes:
        model: the Pinocchio model (gravity is set per call; its own field is not relied on).
        skeleton: the skeleton it was built from.
        scale: metres per skeleton unit.
        masses: (J,) body masses in kg.
        params: (J, 10) dynamic parameters of each body (Pinocchio ``toDynamicParameters``).
        up_axis: index of the vertical axis (1 for Y-up).
    """

    model: Any
    skeleton: Skeleton
    scale: float
    masses: np.ndarray
    params: np.ndarray
    up_axis: int = 1
    foot_corners: dict[int, np.ndarray] = field(default_factory=dict)

    @property
    def nv(self) -> int:
        return int(self.model.nv)

    @property
    def n_bodies(self) -> int:
        return self.skeleton.n_joints

    @property
    def total_mass(self) -> float:
        return float(self.masses.sum())

    def default_gravity(self) -> np.ndarray:
        g = np.zeros(3)
        g[self.up_axis] = -GRAVITY
        return g

    def joint_dofs(self, j: int) -> slice:
        """The velocity indices of skeleton joint ``j``."""
        jm = self.model.joints[j + 1]
        return slice(jm.idx_v, jm.idx_v + jm.nv)


def _rotation_z_to(d: np.ndarray) -> np.ndarray:
    """A rotation matrix taking the z axis to unit vector ``d``."""
    z = np.array([0.0, 0.0, 1.0])
    v = np.cross(z, d)
    s, c = np.linalg.norm(v), float(z @ d)
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]]) / s
    ang = np.arctan2(s, c)
    return np.eye(3) + np.sin(ang) * k + (1 - np.cos(ang)) * (k @ k)


def _bones(skeleton: Skeleton, j: int, scale: float) -> list[np.ndarray]:
    ends = [skeleton.offsets[c] * scale for c in skeleton.children(j)]
    if j in skeleton.end_sites:
        ends.append(np.asarray(skeleton.end_sites[j], dtype=float) * scale)
    return [e for e in ends if np.linalg.norm(e) > 1e-9]


def _cylinder_inertias(skeleton: Skeleton, scale: float, radius_ratio: float) -> list[Any]:
    """Each bone a water-density cylinder from the joint to its child (or end site)."""
    out = []
    for j in range(skeleton.n_joints):
        inertia = pin.Inertia.Zero()
        bones = _bones(skeleton, j, scale)
        for e in bones:
            length = float(np.linalg.norm(e))
            r = radius_ratio * length
            m = WATER_DENSITY * np.pi * r * r * length
            cyl = pin.Inertia.FromCylinder(m, r, length)
            inertia += pin.SE3(_rotation_z_to(e / length), 0.5 * e).act(cyl)
        if not bones:
            r = LEAF_SPHERE_RADIUS
            inertia = pin.Inertia.FromSphere(WATER_DENSITY * 4 / 3 * np.pi * r**3, r)
        out.append(inertia)
    return out


def _table_fractions(skeleton: Skeleton, volumes: np.ndarray) -> np.ndarray:
    """Per-joint mass fractions: table entries split among matching joints, trunk the rest."""
    names = [n.lower() for n in skeleton.names]
    groups: dict[int, list[int]] = {}
    for j, n in enumerate(names):
        for g, (keys, _) in enumerate(ANTHROPOMETRIC_TABLE):
            if any(k in n for k in keys):
                groups.setdefault(g, []).append(j)
                break
    frac = np.zeros(len(names))
    assigned = np.zeros(len(names), bool)
    for g, js in groups.items():
        per_side = ANTHROPOMETRIC_TABLE[g][1] * 2 if g != 0 else ANTHROPOMETRIC_TABLE[g][1]
        v = volumes[js] + 1e-12
        frac[js] = per_side * v / v.sum()
        assigned[js] = True
    rest = max(1.0 - frac.sum(), 0.05)
    free = ~assigned
    if free.any():
        v = volumes[free] + 1e-12
        frac[free] = rest * v / v.sum()
    return frac / frac.sum()


def build_body_model(
    skeleton: Skeleton,
    scale: float,
    *,
    kind: str = "cylinders",
    total_mass: float | None = None,
    radius_ratio: float = DEFAULT_RADIUS_RATIO,
    up_axis: int = 1,
    inertias: list[Any] | None = None,
) -> BodyModel:
    """A Pinocchio model of ``skeleton`` (free-flyer root, spherical joints), SI units.

    ``kind='cylinders'``: each bone a water-density cylinder (MPS06 §4), rescaled to
    ``total_mass`` when given. ``kind='table'``: ``total_mass`` (default 70 kg) split by the
    anthropometric table (keyword match on joint names), each body's shape from its cylinders.
    ``inertias`` (one ``pin.Inertia`` per skeleton joint, in the joint frame, SI) overrides both,
    e.g. the real masses of the DeepMimic URDF. O(J).
    """
    if not scale > 0:
        raise ValueError(f"scale must be positive, got {scale}")
    model = pin.Model()
    model.name = "motionweb-body"
    if inertias is None:
        inertias = _cylinder_inertias(skeleton, scale, radius_ratio)
        masses = np.array([i.mass for i in inertias])
        if kind == "table":
            frac = _table_fractions(skeleton, masses)
            target = frac * (total_mass or 70.0)
            inertias = [_scaled(i, t / max(i.mass, 1e-12)) for i, t in zip(inertias, target, strict=True)]
        elif kind == "cylinders":
            if total_mass is not None:
                k = total_mass / masses.sum()
                inertias = [_scaled(i, k) for i in inertias]
        else:
            raise ValueError(f"unknown body model {kind!r} (cylinders, table)")
    if len(inertias) != skeleton.n_joints:
        raise ValueError(f"{len(inertias)} inertias for {skeleton.n_joints} joints")
    for j in range(skeleton.n_joints):
        if j == 0:
            jid = model.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), skeleton.names[0])
        else:
            placement = pin.SE3(np.eye(3), skeleton.offsets[j] * scale)
            jid = model.addJoint(int(skeleton.parents[j]) + 1, pin.JointModelSpherical(), placement,
                                 skeleton.names[j])
        model.appendBodyToJoint(jid, inertias[j], pin.SE3.Identity())
    params = np.stack([model.inertias[j + 1].toDynamicParameters() for j in range(skeleton.n_joints)])
    masses = params[:, 0].copy()
    return BodyModel(model=model, skeleton=skeleton, scale=float(scale), masses=masses, params=params,
                     up_axis=up_axis)


def _scaled(inertia: Any, k: float) -> Any:
    return pin.Inertia(inertia.mass * k, inertia.lever.copy(), inertia.inertia * k)


def body_model_for(motion: Motion, *, kind: str = "cylinders", total_mass: float | None = None,
                   up_axis: int = 1, humanoid: Any | None = None) -> BodyModel:
    """The body model of ``motion`` in metres (``Motion.metres()`` raises on an unknown unit).

    ``humanoid``: an object with per-joint ``mass`` (J,), ``com`` (J, 3, m, joint frame) and
    ``inertia`` (J, 3, 3, about the com) — e.g. ``store.deepmimic.HumanoidModel`` — whose real
    masses replace the cylinders.
    """
    scale = motion.metres()
    inertias = None
    if humanoid is not None:
        inertias = humanoid_inertias(humanoid, motion.skeleton)
    return build_body_model(motion.skeleton, scale, kind=kind, total_mass=total_mass, up_axis=up_axis,
                            inertias=inertias)


def humanoid_inertias(humanoid: Any, skeleton: Skeleton) -> list[Any]:
    """Per-joint ``pin.Inertia`` from a humanoid description (mass, com, inertia per joint)."""
    mass = np.asarray(humanoid.mass, dtype=float)
    com = np.asarray(humanoid.com, dtype=float).reshape(-1, 3)
    inertia = np.asarray(humanoid.inertia, dtype=float).reshape(-1, 3, 3)
    if mass.shape[0] != skeleton.n_joints:
        raise ValueError(f"humanoid has {mass.shape[0]} bodies, skeleton {skeleton.n_joints} joints")
    return [pin.Inertia(float(mass[j]), com[j], inertia[j]) for j in range(skeleton.n_joints)]


# --------------------------------------------------------------------------- configurations


def configurations(body: BodyModel, motion: Motion) -> np.ndarray:
    """(F, nq) Pinocchio configurations of every frame (root in metres, xyzw quaternions)."""
    f = motion.n_frames
    q = np.empty((f, body.model.nq))
    q[:, :3] = motion.root_positions * body.scale
    rot = motion.rotations / np.linalg.norm(motion.rotations, axis=-1, keepdims=True)
    xyzw = np.concatenate([rot[..., 1:], rot[..., :1]], axis=-1)  # (F, J, 4)
    q[:, 3:7] = xyzw[:, 0]
    q[:, 7:] = xyzw[:, 1:].reshape(f, -1)
    return q


def path_derivatives(body: BodyModel, q: np.ndarray, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """Source-time derivatives q', q'' (F, nv) by central differences on the manifold.

    q'_i = (q_{i+1} ⊖ q_i − q_{i−1} ⊖ q_i) / 2h, q''_i = (q_{i+1} ⊖ q_i + q_{i−1} ⊖ q_i) / h², with
    ⊖ = ``pin.difference`` (tangent space at q_i); end frames copy one-sided values. O(F · nq).
    """
    m = body.model
    f = q.shape[0]
    h = 1.0 / fps
    if f < 3:
        raise ValueError("need at least 3 frames for path derivatives")
    fwd = np.stack([pin.difference(m, q[i], q[i + 1]) for i in range(f - 1)])  # at q_i toward q_{i+1}
    bwd = np.stack([pin.difference(m, q[i], q[i - 1]) for i in range(1, f)])  # at q_i toward q_{i-1}
    d1 = np.empty((f, m.nv))
    d2 = np.empty((f, m.nv))
    d1[1:-1] = (fwd[1:] - bwd[:-1]) / (2 * h)
    d2[1:-1] = (fwd[1:] + bwd[:-1]) / (h * h)
    d1[0] = fwd[0] / h
    d1[-1] = -bwd[-1] / h
    d2[0] = d2[1]
    d2[-1] = d2[-2]
    return d1, d2


# --------------------------------------------------------------------------- path dynamics


@dataclass(frozen=True, eq=False)
class DynamicsTerms:
    """Per-frame coefficients of τ = a p̈ + b ṗ² + c, split by body and gravity axis (MPS06 Eqn. 6).

    Attributes:
        q: (F, nq) configurations; dq, ddq: (F, nv) source-time derivatives q', q''.
        a: (F, nv, B) per-body M q'. b: (F, nv, B) per-body M q'' + C(q, q') q'.
        c: (F, nv, B, 3) per-body gravity term for a unit gravity vector along each axis.
        fps: source frame rate.
    """

    q: np.ndarray
    dq: np.ndarray
    ddq: np.ndarray
    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    fps: float

    @property
    def n_frames(self) -> int:
        return self.q.shape[0]

    def combine(self, gravity: np.ndarray, mass_factors: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(A, B, C), each (F, nv), for a gravity vector and per-body mass multipliers. O(F·nv·B)."""
        g = np.asarray(gravity, dtype=float)
        w = np.ones(self.a.shape[2]) if mass_factors is None else np.asarray(mass_factors, dtype=float)
        return self.a @ w, self.b @ w, np.einsum("fvbk,b,k->fv", self.c, w, g)


def dynamics_terms(body: BodyModel, motion: Motion) -> DynamicsTerms:
    """Per-frame per-body path-dynamics coefficients of ``motion`` (MPS06 §3.1).

    Five joint-torque-regressor evaluations per frame: Y(q, 0, q') for a, Y(q, q', q'') for b
    (gravity off), Y(q, 0, 0) with unit gravity along x, y, z for c. Cost O(F · nv · B).
    """
    m = body.model
    d = m.createData()
    q = configurations(body, motion)
    dq, ddq = path_derivatives(body, q, motion.fps)
    f, nv, nb = q.shape[0], m.nv, body.n_bodies
    pi = body.params  # (B, 10)
    zero = np.zeros(nv)
    reg = pin.computeJointTorqueRegressor
    ya = np.empty((f, nv, nb * 10))
    yb = np.empty((f, nv, nb * 10))
    yc = np.empty((3, f, nv, nb * 10))
    m.gravity = pin.Motion.Zero()
    for i in range(f):
        ya[i] = reg(m, d, q[i], zero, dq[i])
        yb[i] = reg(m, d, q[i], dq[i], ddq[i])
    for k in range(3):
        e = np.zeros(6)
        e[k] = 1.0
        m.gravity = pin.Motion(e)
        for i in range(f):
            yc[k, i] = reg(m, d, q[i], zero, zero)
    a = np.einsum("fvbk,bk->fvb", ya.reshape(f, nv, nb, 10), pi, optimize=True)
    b = np.einsum("fvbk,bk->fvb", yb.reshape(f, nv, nb, 10), pi, optimize=True)
    c = np.einsum("efvbk,bk->fvbe", yc.reshape(3, f, nv, nb, 10), pi, optimize=True)
    m.gravity = pin.Motion(np.concatenate([body.default_gravity(), np.zeros(3)]))
    return DynamicsTerms(q=q, dq=dq, ddq=ddq, a=a, b=b, c=c, fps=float(motion.fps))


def mass_factors(body: BodyModel, factors: dict[str, float]) -> np.ndarray:
    """(B,) per-body multipliers from ``{joint name: factor}`` (ValueError naming the joints)."""
    w = np.ones(body.n_bodies)
    for name, k in factors.items():
        w[body.skeleton.index(name)] = float(k)
    return w
