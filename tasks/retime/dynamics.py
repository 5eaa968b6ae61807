"""Body model and path dynamics for physics-based retiming (design §8, MPS06 §3.1).

A motion q(s) played back with a timing p(t) has velocity q̇ = q' ṗ and acceleration
q̈ = q'' ṗ² + q' p̈ (MPS06 Eqn. 3-4), so the generalized forces it needs are (Eqn. 5-6)

    τ = a(s) p̈ + b(s) ṗ² + c(s),   a = M q',  b = M q'' + C(q, q') q',  c = gravity term.

Inverse dynamics is linear in each body's inertial parameters and in the gravity vector, so we
store every term split by body (and ``c`` split by gravity axis): a new gravity vector or a limb
mass multiplier recombines stored terms without running the dynamics again (the role of the
polynomial-typed Featherstone code of MPS06 §3.1). Per-body terms come from Pinocchio's joint
torque regressor Y(q, v, a) (τ = Y π), contracted with each body's 10 dynamic parameters π_b.

Cost: two regressor calls and one Jacobian pass per frame, O(F · nv · n_bodies); storage the same.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pinocchio as pin
from motionweb.store.motion import Motion, Skeleton
from motionweb.store.numba_cache import njit
from motionweb.tasks.params.retime import DEFAULT_TOTAL_MASS

WATER_DENSITY = 1000.0  # kg / m^3
DEFAULT_RADIUS_RATIO = 0.15  # cylinder radius / bone length
LEAF_SPHERE_RADIUS = 0.04  # m, for leaf joints with no bone
GRAVITY = 9.81

#: Segment mass fractions of total body mass (Winter, Biomechanics and Motor Control of Human
#: Movement, 4th ed., Table 4.1; per side for limbs). Trunk = pelvis 0.142 + abdomen and thorax 0.355,
#: of which 0.01 per side sits on the shoulder girdle (the bodies of an arm before the upper arm), so
#: that the long clavicle bones of mocap skeletons do not take the chest's mass by their volume.
SEGMENT_FRACTIONS: dict[str, float] = {
    "pelvis": 0.142, "torso": 0.335, "shoulder": 0.01, "head_neck": 0.081, "upper_arm": 0.028, "forearm": 0.016, "hand": 0.006,
    "thigh": 0.100, "shank": 0.0465, "foot": 0.0145,
}


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


def segments(skeleton: Skeleton, scale: float, up_axis: int = 1) -> list[str]:
    """The anthropometric segment (a key of :data:`SEGMENT_FRACTIONS`) of each body, from the skeleton's shape.

    Body ``j`` spans joint ``j`` to its children. Names are not trusted (a joint named "hip" carries
    the thigh in one skeleton and the pelvis in another); the structure decides: a leg is the
    path from the root to a foot joint (:func:`motionweb.tasks.retime.contacts.find_feet`), its two
    longest bodies thigh and shank, those above pelvis, the foot joint's subtree foot. The spine
    is the path to the highest leaf; an arm is the path from the spine to any other leaf, its
    longest body the upper arm and the longest after it the forearm (a clavicle can be longer than
    a forearm: CMU subjects 14, 135), those before shoulder (clavicle), the forearm's descendants
    hand. Spine bodies past the highest arm branch are head and neck; the root is
    pelvis; the rest torso. O(J²).
    """
    from motionweb.tasks.retime.contacts import find_feet, rest_positions

    n = skeleton.n_joints
    seg = ["torso"] * n
    seg[0] = "pelvis"
    rest = rest_positions(skeleton, scale)
    lengths = np.array([sum(float(np.linalg.norm(e)) for e in _bones(skeleton, j, scale)) for j in range(n)])

    def path(j: int) -> list[int]:  # root (excluded) .. j
        out = []
        while j > 0:
            out.append(j)
            j = int(skeleton.parents[j])
        return out[::-1]

    def descendants(j: int) -> list[int]:
        out, todo = [], list(skeleton.children(j))
        while todo:
            c = todo.pop()
            out.append(c)
            todo += skeleton.children(c)
        return out

    def limb(chain: list[int], upper: str, lower: str, above: str, below: str, upper_longest: bool) -> None:
        if len(chain) < 2:
            return
        if upper_longest:  # the upper body is the longest one, the lower the longest after it
            k0 = min(range(len(chain) - 1), key=lambda k: (-lengths[chain[k]], k))
            k1 = min(range(k0 + 1, len(chain)), key=lambda k: (-lengths[chain[k]], k))
        else:  # the two longest, in chain order (a shank can be longer than its thigh)
            k0, k1 = sorted(sorted(range(len(chain)), key=lambda k: (-lengths[chain[k]], k))[:2])
        for j in chain[:k0]:
            seg[j] = above
        seg[chain[k0]] = upper
        for j in chain[k0 + 1:k1 + 1]:
            seg[j] = lower
        for j in descendants(chain[k1]):
            seg[j] = below

    feet = find_feet(skeleton, scale, up_axis)
    in_leg: set[int] = set()
    for foot in feet:
        chain = path(foot.joint)
        in_leg |= set(chain) | set(descendants(foot.joint))
        limb(chain, "thigh", "shank", "pelvis", "foot", upper_longest=False)
        for j in [foot.joint, *descendants(foot.joint)]:
            seg[j] = "foot"
    tips = {j: rest[j] + (np.asarray(skeleton.end_sites[j], float) * scale if j in skeleton.end_sites else 0.0)
            for j in range(n) if not skeleton.children(j)}
    free = [j for j in tips if j not in in_leg and j > 0]
    if not free:
        return seg
    head = max(free, key=lambda j: tips[j][up_axis])
    spine = path(head)
    branches = []
    for leaf in free:
        if leaf == head:
            continue
        chain = path(leaf)
        k = 0
        while k < len(chain) and k < len(spine) and chain[k] == spine[k]:
            k += 1
        if k > 0 and chain[k:]:
            branches.append((k, chain[k:]))
    top = max((k for k, _ in branches), default=len(spine) - 1)
    for j in spine[top:]:
        seg[j] = "head_neck"
    done: set[int] = set()
    for _, chain in sorted(branches, key=lambda b: -len(b[1])):  # the longest path of each arm (to a finger)
        if chain[0] in done:
            continue
        done.add(chain[0])
        limb(chain, "upper_arm", "forearm", "shoulder", "hand", upper_longest=True)
    return seg


def segment_fractions(skeleton: Skeleton, scale: float, volumes: np.ndarray, up_axis: int = 1) -> np.ndarray:
    """(J,) mass fractions: each segment's share of :data:`SEGMENT_FRACTIONS` split among its bodies
    by volume (each side of a limb its own share), renormalized to sum to 1."""
    seg = segments(skeleton, scale, up_axis)
    frac = np.zeros(len(seg))
    groups: dict[tuple[str, int], list[int]] = {}
    for j, name in enumerate(seg):
        groups.setdefault((name, limb_root(skeleton, j, seg)), []).append(j)
    for (name, _), js in groups.items():
        v = volumes[js] + 1e-12
        frac[js] = SEGMENT_FRACTIONS[name] * v / v.sum()
    # a segment missing from this skeleton (no arms, say) leaves its share to the others
    return frac / frac.sum()


def limb_root(skeleton: Skeleton, j: int, seg: list[str]) -> int:
    """The topmost body of ``j``'s run of bodies with the same segment (tells left from right)."""
    while j > 0 and seg[int(skeleton.parents[j])] == seg[j]:
        j = int(skeleton.parents[j])
    return j if seg[j] not in ("pelvis", "torso", "head_neck") else -1


def build_body_model(
    skeleton: Skeleton,
    scale: float,
    *,
    kind: str,
    total_mass: float | None,
    radius_ratio: float = DEFAULT_RADIUS_RATIO,
    up_axis: int = 1,
    inertias: list[Any] | None = None,
) -> BodyModel:
    """A Pinocchio model of ``skeleton`` (free-flyer root, spherical joints), SI units.

    ``kind`` and ``total_mass`` are required (their defaults: ``RetimeParams.body_model`` and
    ``total_mass``). ``kind='cylinders'``: each bone a water-density cylinder (MPS06 §4), rescaled to
    ``total_mass`` when given. ``kind='table'``: ``total_mass`` (None: 70 kg) split by the
    anthropometric table (:func:`segments` finds each body's segment from the skeleton's
    structure), each body's shape (inertia) from its cylinders.
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
            frac = segment_fractions(skeleton, scale, masses, up_axis)
            target = frac * (total_mass or DEFAULT_TOTAL_MASS)
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


def body_model_for(motion: Motion, *, kind: str, total_mass: float | None,
                   up_axis: int = 1, humanoid: Any | None = None) -> BodyModel:
    """The body model of ``motion`` in metres (``Motion.metres()`` raises on an unknown unit), MPS06 §4.

    ``kind``, ``total_mass``: as :func:`build_body_model` (required; ``RetimeParams`` holds their defaults).

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


def path_derivatives(body: BodyModel, q: np.ndarray, fps: float, smoothing_s: float
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Source-time derivatives q', q'' (F, nv): a local quadratic fit on the manifold (Savitzky-Golay).

    At frame i the tangent offsets d_j = q_{i+j} ⊖ q_i (``pin.difference``, tangent space at q_i)
    for |j| ≤ m, m = max(1, round(``smoothing_s`` · fps)), are fitted by least squares with
    a + q' (jh) + q'' (jh)²/2. Within m frames of a clip's end the window keeps its 2m + 1 frames,
    shifted inside the clip (scipy's ``savgol_filter(mode="interp")``): q'' is that window's
    curvature, exactly as noisy as anywhere else, and q' its slope at frame i. A window cut short
    instead (m + 1 frames at the end frame) fits a quadratic to half the frames and extrapolates it:
    at m = 10 its q'' has 26x the variance of a full window's (its q' 97x; shifted: 15x), and a clip
    that ends mid-stride ends with hundreds of N·m that no motion asked for (16_49's last frames). m = 1 is the central difference
    q'_i = (d_1 − d_{−1}) / 2h, q''_i = (d_1 + d_{−1}) / h². Mocap at 120 fps differentiated twice
    over one frame turns millimetres of marker noise into tens of m/s². ``RetimeParams.smoothing_s``'s ±80 ms
    (±10 frames at 120 fps; the q'' estimate's gain halves at ~5.5 Hz, ±40 ms: ~10.6 Hz) keeps
    the ground reaction forces of walks and runs and removes the ~9 Hz, ±0.3 g wobble of the body
    model's centre of mass that ±40 ms leaves in CMU flights (subject 16: runs' stance frames whose
    root force no contact explains drop from 40-60 % to 8-40 %, walks' from ~8 % to ~1.5 %).
    O(F · m · nq).
    """
    m = body.model
    f = q.shape[0]
    h = 1.0 / fps
    if f < 3:
        raise ValueError("need at least 3 frames for path derivatives")
    w = max(1, int(round(smoothing_s * fps)))
    n = min(2 * w, f - 1)  # frames past the first of a full window
    offs = {j: np.stack([pin.difference(m, q[i], q[i + j]) if 0 <= i + j < f else np.full(m.nv, np.nan)
                         for i in range(f)]) for j in range(-w, w + 1) if j}
    for j in range(w + 1, n + 1):  # the end frames' shifted windows reach up to 2w frames away
        offs[j], offs[-j] = np.full((f, m.nv), np.nan), np.full((f, m.nv), np.nan)
        for i in [*range(min(w, f)), *range(max(f - w, 0), f)]:
            if i + j < f:
                offs[j][i] = pin.difference(m, q[i], q[i + j])
            if i - j >= 0:
                offs[-j][i] = pin.difference(m, q[i], q[i - j])
    d1 = np.empty((f, m.nv))
    d2 = np.empty((f, m.nv))
    fits: dict[tuple[int, int], np.ndarray] = {}
    for i in range(f):
        lo = min(max(-w, -i), f - 1 - i - n)  # the window [i + lo, i + lo + n] inside the clip
        hi = lo + n
        if (lo, hi) not in fits:
            t = np.arange(lo, hi + 1) * h
            fits[(lo, hi)] = np.linalg.pinv(np.stack([np.ones_like(t), t, 0.5 * t * t], axis=1))[1:]  # (2, n)
        coef = fits[(lo, hi)]
        d = np.stack([offs[j][i] if j else np.zeros(m.nv) for j in range(lo, hi + 1)])  # (n, nv)
        d1[i], d2[i] = coef @ d
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

    def combine(self, gravity: np.ndarray, mass_factors: np.ndarray | None = None,
                weight_factors: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(A, B, C), each (F, nv), for a gravity vector and per-body (B,) multipliers: of the mass
        (inertia and weight) and, on top of it, of the weight alone (the gravity term). O(F·nv·B)."""
        g = np.asarray(gravity, dtype=float)
        ones = np.ones(self.a.shape[2])
        w = ones if mass_factors is None else np.asarray(mass_factors, dtype=float)
        wg = w * (ones if weight_factors is None else np.asarray(weight_factors, dtype=float))
        return self.a @ w, self.b @ w, np.einsum("fvbk,b,k->fv", self.c, wg, g)


def dynamics_terms(body: BodyModel, motion: Motion, smoothing_s: float) -> DynamicsTerms:
    """Per-frame per-body path-dynamics coefficients of ``motion`` (MPS06 §3.1).

    ``smoothing_s``: half-width of the derivative fit (:func:`path_derivatives`; required, its
    default is ``RetimeParams.smoothing_s``).

    Two joint-torque-regressor evaluations per frame, each contracted with the bodies' dynamic
    parameters at once: Y(q, 0, q') for a, Y(q, q', q'') for b (gravity off); c from the bodies'
    centre-of-mass Jacobians (:func:`gravity_terms`). Cost O(F · nv · B); the slow reference
    (five regressors, tests/naive.py) is the same sums.
    """
    m = body.model
    d = m.createData()
    q = configurations(body, motion)
    dq, ddq = path_derivatives(body, q, motion.fps, smoothing_s)
    f, nv, nb = q.shape[0], m.nv, body.n_bodies
    pi = body.params  # (B, 10)
    zero = np.zeros(nv)
    reg = pin.computeJointTorqueRegressor
    a = np.empty((f, nv, nb))
    b = np.empty((f, nv, nb))
    m.gravity = pin.Motion.Zero()
    for i in range(f):  # (nv, B, 10) · (B, 10): each body's 10 columns with its own parameters
        np.einsum("vbk,bk->vb", reg(m, d, q[i], zero, dq[i]).reshape(nv, nb, 10), pi, out=a[i])
        np.einsum("vbk,bk->vb", reg(m, d, q[i], dq[i], ddq[i]).reshape(nv, nb, 10), pi, out=b[i])
    m.gravity = pin.Motion(np.concatenate([body.default_gravity(), np.zeros(3)]))
    return DynamicsTerms(q=q, dq=dq, ddq=ddq, a=a, b=b, c=gravity_terms(body, q, d), fps=float(motion.fps))


def gravity_terms(body: BodyModel, q: np.ndarray, data: pin.Data | None = None) -> np.ndarray:
    """(F, nv, B, 3) generalized force of each body's weight under a unit gravity along x, y, z.

    Gravity acts at each body's centre of mass p_b: its share of τ = M q̈ + h − Σ J_bᵀ m_b g is
    −m_b J_{p_b}ᵀ e, with J_{p_b} = J_v − [p_b]× J_ω from the body's world-frame joint Jacobian
    (the columns of its supporting joints). One ``computeJointJacobians`` per frame, O(F · B · nv).
    ``data``: a scratch ``pin.Data`` of ``body.model`` to reuse (``createData`` costs ~35 ms for
    the 31 bodies of a CMU skeleton, a third of a 160-frame clip's dynamics).
    """
    m = body.model
    d = m.createData() if data is None else data
    f, nv, nb = q.shape[0], m.nv, body.n_bodies
    support = np.zeros((nb, nv), bool)  # dofs moving body b
    for j in range(nb):
        for k in m.supports[j + 1]:
            if k:
                support[j, m.idx_vs[k]:m.idx_vs[k] + m.nvs[k]] = True
    jac = np.empty((f, 6, nv))  # WORLD: linear rows = velocity of the body point at the origin
    place = np.empty((f, nb, 4, 4))
    for i in range(f):
        pin.computeJointJacobians(m, d, q[i])
        jac[i] = d.J
        place[i] = [d.oMi[j + 1].homogeneous for j in range(nb)]
    mass = body.params[:, 0]
    # m_b p_b in the world: mass times the joint origin plus the rotated first moment m·c
    h = mass[:, None] * place[:, :, :3, 3] + np.einsum("fbij,bj->fbi", place[:, :, :3, :3], body.params[:, 1:4])
    out = np.empty((f, nv, nb, 3))
    weight_jacobians(jac, h, mass, support, out)
    return out


@njit(cache=True)
def weight_jacobians(jac: np.ndarray, h: np.ndarray, mass: np.ndarray, support: np.ndarray, out: np.ndarray) -> None:
    """out[f, v, b] = −(m_b J_v − (m_b p_b) × J_ω)[:, v] where body b moves with dof v, else 0.

    jac (F, 6, nv) world-frame Jacobians, h (F, B, 3) first moments m_b p_b, mass (B,),
    support (B, nv) bool, out (F, nv, B, 3). O(F · nv · B).

    Bounds: writes exactly the (F, nv, B, 3) cells given by jac's and h's shapes, ``out``'s shape as
    its caller allocates it.
    """
    f, _, nv = jac.shape
    nb = h.shape[1]
    for i in range(f):
        for v in range(nv):
            jx, jy, jz = jac[i, 0, v], jac[i, 1, v], jac[i, 2, v]
            wx, wy, wz = jac[i, 3, v], jac[i, 4, v], jac[i, 5, v]
            for b in range(nb):
                if support[b, v]:
                    hx, hy, hz = h[i, b, 0], h[i, b, 1], h[i, b, 2]
                    out[i, v, b, 0] = -(mass[b] * jx - (hy * wz - hz * wy))
                    out[i, v, b, 1] = -(mass[b] * jy - (hz * wx - hx * wz))
                    out[i, v, b, 2] = -(mass[b] * jz - (hx * wy - hy * wx))
                else:
                    out[i, v, b, 0] = 0.0
                    out[i, v, b, 1] = 0.0
                    out[i, v, b, 2] = 0.0


def centre_of_mass(body: BodyModel, q: np.ndarray) -> np.ndarray:
    """(F, 3) the whole body's centre of mass (m) at configurations ``q`` (F, nq). O(F · B)."""
    data = body.model.createData()
    return np.array([pin.centerOfMass(body.model, data, qi) for qi in q]).reshape(-1, 3)


def mass_factors(body: BodyModel, factors: dict[str, float]) -> np.ndarray:
    """(B,) per-body multipliers from ``{joint name: factor}`` (ValueError naming the joints)."""
    w = np.ones(body.n_bodies)
    for name, k in factors.items():
        w[body.skeleton.index(name)] = float(k)
    return w
