"""The demo corpus's clip generators, one per category: steady gaits (walk, run) along arcs, jumps
and one-legged hops with exact ballistic flights, and stationary clips (kick, punch, reach, sit,
idle) with effector targets. Each returns a `ClipSpec` (plan plus the ground truth it knows, in the
clip's local frame); `GENERATORS` maps a category to its generator.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from motionweb.store.demo.rig import (
    SIDES,
    UNIT_X,
    UNIT_Y,
    ClipSpec,
    G,
    Plan,
    Plant,
    Rig,
    build_motion,
    foot_track,
    frame_times,
    hermite,
    lateral_sign,
    level_head,
    max_root_heights,
    neutral_plan,
    override_foot,
    qypr,
    root_height_for,
    rot_y,
    smooth,
)
from motionweb.store.kinematics import forward_kinematics, quat_rotate

# --------------------------------------------------------------------------------------------------
# locomotion: walk and run


@dataclass(frozen=True)
class Gait:
    """Parameters of a steady gait along an arc (speed m/s, turn rad/s, cadence steps/s)."""

    speed: float
    turn: float
    cadence: float
    duty: float
    width: float
    lift: float
    bob: float
    sway: float
    lean: float
    pelvis_yaw: float
    heel_frac: float
    heel_pitch: float
    arm_swing: float
    elbow: float
    run: bool
    phase: float = 0.0
    anchor: float = 0.42
    toe_out: float = math.radians(4.0)

    @property
    def period(self) -> float:
        return 2.0 / self.cadence

    def path(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Root ground path (n, 3) and heading (n,) at times t."""
        t = np.asarray(t, dtype=np.float64)
        yaw = self.turn * t
        if abs(self.turn) < 1e-9:
            x, z = np.zeros_like(t), self.speed * t
        else:
            x = self.speed * (1.0 - np.cos(yaw)) / self.turn
            z = self.speed * np.sin(yaw) / self.turn
        return np.stack([x, np.zeros_like(t), z], -1), yaw

    def left_on(self) -> float:
        """A left touchdown time."""
        return self.phase * self.period

    def plants(self, rig: Rig, t_lo: float, t_hi: float) -> dict[str, list[Plant]]:
        per, stance = self.period, self.duty * self.period
        out: dict[str, list[Plant]] = {}
        for side, shift in (("left", 0.0), ("right", 0.5 * per)):
            k0 = math.floor((t_lo - self.left_on() - shift) / per) - 1
            k1 = math.ceil((t_hi - self.left_on() - shift) / per) + 1
            lst = []
            for k in range(k0, k1 + 1):
                on = self.left_on() + shift + k * per
                ta = on + self.anchor * stance
                p, yaw = self.path(np.array([ta]))
                pos = p[0] + rot_y(yaw[0], UNIT_X * lateral_sign(side) * self.width / 2) + UNIT_Y * rig.ankle_height
                lst.append(Plant(t_on=on, t_off=on + stance, ankle=pos, yaw=float(yaw[0] - lateral_sign(side) * self.toe_out),
                                 t_heel=on + self.heel_frac * stance, heel_pitch=self.heel_pitch))
            out[side] = lst
        return out

    def cycle(self, t: np.ndarray) -> np.ndarray:
        """Gait phase angle, 0 at a left touchdown."""
        return 2.0 * np.pi * (t - self.left_on()) / self.period

    def root(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Root ground position with sway (n, 3), bob (n,), rotation (n, 4); height excluded."""
        p, yaw = self.path(t)
        ph = self.cycle(t)
        mid = ph - np.pi * self.duty  # 0 at left mid-stance
        p = p + (self.sway * np.cos(mid))[:, None] * rot_y(yaw, UNIT_X)
        bob = (-1.0 if self.run else 1.0) * self.bob * np.cos(2.0 * mid)
        rot = qypr(yaw - self.pelvis_yaw * np.cos(ph), self.lean * 0.5, 0.0)
        return p, bob, rot

    def upper(self, plan: Plan, t: np.ndarray) -> None:
        ph = self.cycle(t)
        c = np.cos(ph)
        plan.spine[:, 0] = self.lean * 0.6
        plan.spine[:, 1] = 1.3 * self.pelvis_yaw * c
        for side in SIDES:
            sw = -lateral_sign(side) * self.arm_swing * c
            plan.arms[side][:, 0] = math.radians(4.0) + sw
            plan.arms[side][:, 1] = math.radians(10.0 if self.run else 6.0)
            plan.arms[side][:, 2] = self.elbow + 0.4 * np.maximum(sw, 0.0)


def _gait_clip(rig: Rig, gait: Gait, duration: float, fps: float, label: str) -> ClipSpec:
    t = frame_times(duration, fps)
    plants = gait.plants(rig, 0.0, t[-1])
    feet = {s: foot_track(rig, t, plants[s], gait.lift) for s in SIDES}
    plan = neutral_plan(rig, t, feet)
    ground, bob, rot = gait.root(t)
    lim = max_root_heights(rig, ground, rot, feet, 0.975 * rig.leg)
    base = float(min(np.min(lim - bob), rig.stand_height - 0.01))
    plan.root_pos = ground + (base + bob)[:, None] * UNIT_Y
    plan.root_rot = rot
    gait.upper(plan, t)
    level_head(plan, np.full(len(t), gait.lean * 0.5))
    flights = _flight_gaps(plants, 0.0, float(t[-1]))
    params = {"speed": gait.speed, "turn_rate_deg_s": math.degrees(gait.turn), "cadence": gait.cadence,
              "duty_factor": gait.duty, "step_width": gait.width, "stride_length": gait.speed * gait.period,
              "root_height": base, "bob": gait.bob}
    return ClipSpec(plan, [{"label": label, "t0": 0.0, "t1": float(t[-1])}], [], flights, plants, params)


def _flight_gaps(plants: dict[str, list[Plant]], t_lo: float, t_hi: float) -> list[tuple[float, float]]:
    """Time intervals inside (t_lo, t_hi) where no foot is planted."""
    iv = sorted((p.t_on, p.t_off) for s in SIDES for p in plants[s])
    gaps, reach = [], -np.inf
    for a, b in iv:
        if a > reach > t_lo and a < t_hi:
            gaps.append((float(reach), float(a)))
        reach = max(reach, b)
    return gaps


def walk_gait(v: int, rng: np.random.Generator) -> Gait:
    speed = (0.95, 1.3, 1.6)[v % 3] * (1.0 + 0.04 * rng.uniform(-1, 1)) * (1.0 + 0.05 * (v // 3))
    turn = math.radians((0.0, 30.0, -22.0, 40.0, -40.0, 12.0)[v % 6] + rng.uniform(-4, 4))
    return Gait(speed=speed, turn=turn, cadence=1.45 + 0.38 * speed, duty=0.63 - 0.03 * (speed - 1.0),
                width=0.2 + 0.02 * rng.uniform(-1, 1), lift=0.07 + 0.02 * speed, bob=0.012 + 0.008 * speed,
                sway=0.02, lean=math.radians(3.0 + 3.0 * speed), pelvis_yaw=math.radians(4.0 + 2.0 * speed),
                heel_frac=0.62, heel_pitch=math.radians(28.0 + 6.0 * speed), arm_swing=math.radians(9.0 + 9.0 * speed),
                elbow=math.radians(14.0), run=False, phase=float(rng.uniform(0, 1)))


def _run_gait(v: int, rng: np.random.Generator) -> Gait:
    speed = (2.6, 3.2, 3.8)[v % 3] * (1.0 + 0.04 * rng.uniform(-1, 1)) * (1.0 + 0.05 * (v // 3))
    turn = math.radians((0.0, -24.0, 30.0, 45.0, -45.0, 15.0)[v % 6] + rng.uniform(-4, 4))
    return Gait(speed=speed, turn=turn, cadence=2.55 + 0.12 * speed, duty=0.40 - 0.02 * (speed - 3.0),
                width=0.14, lift=0.16 + 0.03 * speed, bob=G / (2.0 * np.pi * (2.55 + 0.12 * speed)) ** 2, sway=0.01, lean=math.radians(8.0 + 2.0 * speed),
                pelvis_yaw=math.radians(7.0), heel_frac=0.4, heel_pitch=math.radians(38.0),
                arm_swing=math.radians(28.0), elbow=math.radians(85.0), run=True, phase=float(rng.uniform(0, 1)))


def _gen_walk(rig: Rig, v: int, rng: np.random.Generator, fps: float) -> ClipSpec:
    return _gait_clip(rig, walk_gait(v, rng), 4.0 + 0.5 * rng.uniform(0, 1), fps, "walk")


def _gen_run(rig: Rig, v: int, rng: np.random.Generator, fps: float) -> ClipSpec:
    return _gait_clip(rig, _run_gait(v, rng), 3.0 + 0.5 * rng.uniform(0, 1), fps, "run")


# --------------------------------------------------------------------------------------------------
# shared pose helpers for the stationary and jumping clips


def _keys(t: np.ndarray, knots: list[tuple[float, Any]]) -> np.ndarray:
    """Values eased between (time, value) knots (zero slopes), (F, D)."""
    kt = np.array([k for k, _ in knots])
    kp = np.array([np.atleast_1d(np.asarray(v, dtype=np.float64)) for _, v in knots])
    return hermite(t, kt, kp)


def _pulse(t: np.ndarray, t_a: float, t_apex: float, t_b: float, hold: float = 0.0) -> np.ndarray:
    """0 -> 1 (eased) on [t_a, t_apex], 1 for ``hold`` seconds, back to 0 by t_b."""
    up = smooth((t - t_a) / (t_apex - t_a))
    down = 1.0 - smooth((t - t_apex - hold) / (t_b - t_apex - hold))
    return np.where(t <= t_apex, up, np.where(t <= t_apex + hold, 1.0, down))


def _snap(t: float, fps: float) -> float:
    """The frame time nearest to t."""
    return round(t * fps) / fps


def _standing_plants(rig: Rig, feet: dict[str, tuple[float, float, float]], t_end: float) -> dict[str, list[Plant]]:
    """One plant per foot lasting the whole clip; feet[side] = (x, z, yaw)."""
    return {s: [Plant(t_on=-1.0, t_off=t_end + 1.0, ankle=np.array([x, rig.ankle_height, z]), yaw=yaw)]
            for s, (x, z, yaw) in feet.items()}


def _apply_root(plan: Plan, pos: np.ndarray, yaw: np.ndarray, pitch: np.ndarray, roll: Any = 0.0) -> None:
    plan.root_pos = pos
    plan.root_rot = qypr(yaw, pitch, roll)


def _hip(rig: Rig, plan: Plan, side: str, i: int) -> np.ndarray:
    return plan.root_pos[i] + quat_rotate(plan.root_rot[i], rig.hip_offset[side])


def _dir(elev: float, azim: float) -> np.ndarray:
    return np.array([math.sin(azim) * math.cos(elev), math.sin(elev), math.cos(azim) * math.cos(elev)])


# --------------------------------------------------------------------------------------------------
# jumps: crouch, take-off, exact ballistic flight, landing, recovery


@dataclass
class Jump:
    """A two-footed jump planned from a still, ready stance."""

    root_t: list[float]
    root_p: list[np.ndarray]
    root_v: list[np.ndarray]
    t0: float
    t1: float
    p0: np.ndarray
    v0: np.ndarray
    plants: dict[str, list[Plant]]
    carry: dict[str, tuple[list[float], list[np.ndarray]]]
    pose: list[tuple[float, np.ndarray]]  # (time, [pelvis pitch, spine pitch, arm flex, elbow])
    actions: list[dict[str, Any]]
    t_end: float
    params: dict[str, Any]

    def root(self, t: np.ndarray) -> np.ndarray:
        """Root positions; on [t0, t1] exactly the parabola under gravity."""
        out = hermite(t, self.root_t, np.array(self.root_p), np.array(self.root_v))
        m = (t >= self.t0) & (t <= self.t1)
        dt = (t[m] - self.t0)[:, None]
        out[m] = self.p0 + self.v0 * dt - 0.5 * G * dt * dt * UNIT_Y
        return out


def plan_jump(rig: Rig, t_ready: float, root_ready: np.ndarray, stance: dict[str, Plant], apex: float,
              distance: float, width: float = 0.2) -> Jump:
    """Plan a jump: ``apex`` metres of root rise after take-off, ``distance`` metres of flight
    along +Z. ``stance`` holds each foot's current plant (its t_off is replaced by the take-off)."""
    t_c = t_ready + 0.45
    t0 = t_c + 0.25
    crouch = 0.2 + 0.1 * apex
    heel = math.radians(30.0)
    feet_z = float(np.mean([p.ankle[2] for p in stance.values()]))
    feet_x = float(np.mean([p.ankle[0] for p in stance.values()]))
    take = {s: replace(p, t_off=t0, t_heel=t0 - 0.13, heel_pitch=heel) for s, p in stance.items()}
    pitch0, pitch1 = math.radians(5.0), math.radians(12.0)
    z0 = feet_z + 0.04 + 0.07 * distance
    ank0 = {s: p.pivot_ankle(rig, np.array([heel]))[0] for s, p in take.items()}
    y0 = root_height_for(rig, np.array([feet_x, 0.0, z0]), qypr(0.0, pitch0), ank0, 0.965 * rig.leg)
    ahead = 0.10
    rel_land = {s: np.array([lateral_sign(s) * width / 2, rig.ankle_height, ahead]) for s in SIDES}
    y1 = root_height_for(rig, np.zeros(3), qypr(0.0, pitch1), rel_land, 0.95 * rig.leg)
    vy = math.sqrt(2.0 * G * apex)
    tf = (vy + math.sqrt(vy * vy + 2.0 * G * (y0 - y1))) / G
    vh = distance / tf
    p0 = np.array([feet_x, y0, z0])
    v0 = np.array([0.0, vy, vh])
    t1 = t0 + tf
    p1 = p0 + v0 * tf - 0.5 * G * tf * tf * UNIT_Y
    v1 = v0 - G * tf * UNIT_Y
    land = {s: Plant(t_on=t1, t_off=t1 + 100.0, ankle=np.array([p1[0], 0.0, p1[2]]) + rel_land[s] * [1, 0, 1]
                     + rig.ankle_height * UNIT_Y, yaw=stance[s].yaw) for s in SIDES}
    t_abs = 0.25
    depth = max(0.16 + 0.2 * apex, abs(v1[1]) * t_abs / 3.0)
    t_a = t1 + t_abs
    p_a = np.array([p1[0], y1 - depth, p1[2] + 0.4 * vh * t_abs])
    t_r = t_a + 0.6 + 0.3 * apex
    land_z = p1[2] + ahead
    p_r = np.array([p1[0], root_ready[1], land_z - 0.01])
    zero = np.zeros(3)
    root_t = [t_ready, t_c, t0, t1, t_a, t_r]
    root_p = [root_ready, root_ready + np.array([0.0, -crouch, -0.05]), p0, p1, p_a, p_r]
    root_v = [zero, zero, v0, v1, zero, zero]
    mid = 0.5 * (t0 + t1)
    rel0 = {s: ank0[s] - p0 for s in SIDES}
    rel1 = {s: land[s].ankle - p1 for s in SIDES}
    carry = {s: ([t0, mid, t1], [rel0[s], 0.5 * (rel0[s] + rel1[s]) + (0.15 + 0.3 * apex) * UNIT_Y, rel1[s]])
             for s in SIDES}
    pose = [
        (t_ready, np.array([0.0, 0.0, 0.07, 0.2])),
        (t_c, np.array([0.45, 0.35, -0.8, 0.3])),
        (t0, np.array([pitch0, 0.05, 1.6, 0.5])),
        (mid, np.array([pitch0, 0.1, 1.7, 0.5])),
        (t1, np.array([pitch1, 0.15, 0.7, 0.4])),
        (t_a, np.array([0.4, 0.35, 0.3, 0.4])),
        (t_r, np.array([0.0, 0.0, 0.07, 0.2])),
    ]
    actions = [{"label": "crouch", "t0": t_ready, "t1": t_c}, {"label": "takeoff", "t0": t_c, "t1": t0},
               {"label": "flight", "t0": t0, "t1": t1}, {"label": "landing", "t0": t1, "t1": t_a},
               {"label": "recover", "t0": t_a, "t1": t_r}]
    plants = {s: [take[s], land[s]] for s in SIDES}
    params = {"apex_height": apex, "distance": distance, "flight_time": tf, "takeoff_velocity": v0,
              "landing_velocity": v1, "takeoff_height": y0, "landing_height": y1}
    return Jump(root_t, root_p, root_v, t0, t1, p0, v0, plants, carry, pose, actions, t_r, params)


def apply_jump(rig: Rig, plan: Plan, jump: Jump, weight: np.ndarray | None = None) -> None:
    """Drive root, flight feet and jump poses of ``plan`` from the jump (poses blended in by weight)."""
    t = plan.t
    root = jump.root(t)
    pose = _keys(t, jump.pose)
    w = np.ones(len(t)) if weight is None else weight
    m = (t > jump.t0) & (t < jump.t1)
    for s in SIDES:
        kt, rel = jump.carry[s]
        ankle = root + hermite(t, kt, np.array(rel))
        override_foot(plan.feet[s], m.astype(np.float64), ankle)
    plan.root_pos = np.where(t[:, None] >= jump.root_t[0], root, plan.root_pos)
    yaw = np.zeros(len(t))
    rot = qypr(yaw, pose[:, 0])
    blend = (w[:, None] > 0)
    plan.root_rot = np.where(blend & (t[:, None] >= jump.root_t[0]), rot, plan.root_rot)
    plan.spine[:, 0] = (1 - w) * plan.spine[:, 0] + w * pose[:, 1]
    for s in SIDES:
        plan.arms[s][:, 0] = (1 - w) * plan.arms[s][:, 0] + w * pose[:, 2]
        plan.arms[s][:, 2] = (1 - w) * plan.arms[s][:, 2] + w * pose[:, 3]
    level_head(plan, pose[:, 0], 0.6)


def _gen_jump(rig: Rig, v: int, rng: np.random.Generator, fps: float) -> ClipSpec:
    apex = (0.25, 0.35, 0.45)[v % 3] + 0.03 * rng.uniform(-1, 1)
    distance = (0.0, 0.6, 1.1)[(v + v // 3) % 3] + 0.1 * rng.uniform(0, 1)
    width = 0.2 + 0.02 * rng.uniform(-1, 1)
    t_ready = 0.4 + 0.2 * rng.uniform(0, 1)
    stance = {s: Plant(t_on=-1.0, t_off=100.0, ankle=np.array([lateral_sign(s) * width / 2, rig.ankle_height, 0.0]),
                       yaw=-lateral_sign(s) * math.radians(5.0)) for s in SIDES}
    ready = np.array([0.0, rig.stand_height - 0.02, 0.0])
    jump = plan_jump(rig, t_ready, ready, stance, apex, distance, width)
    t = frame_times(jump.t_end + 0.5, fps)
    feet = {s: foot_track(rig, t, jump.plants[s], 0.0) for s in SIDES}
    plan = neutral_plan(rig, t, feet)
    plan.root_pos = np.broadcast_to(ready, (len(t), 3)).copy()
    apply_jump(rig, plan, jump)
    actions = [{"label": "stand", "t0": 0.0, "t1": t_ready}, *jump.actions,
               {"label": "stand", "t0": jump.t_end, "t1": float(t[-1])}]
    return ClipSpec(plan, actions, [], [(jump.t0, jump.t1)], jump.plants, jump.params)


# --------------------------------------------------------------------------------------------------
# stationary clips: kick, punch, reach, sit, idle


def _stationary(rig: Rig, duration: float, fps: float, feet: dict[str, tuple[float, float, float]]
                ) -> tuple[np.ndarray, Plan, dict[str, list[Plant]]]:
    t = frame_times(duration, fps)
    plants = _standing_plants(rig, feet, float(t[-1]))
    plan = neutral_plan(rig, t, {s: foot_track(rig, t, plants[s], 0.0) for s in SIDES})
    return t, plan, plants


def _gen_kick(rig: Rig, v: int, rng: np.random.Generator, fps: float) -> ClipSpec:
    side = ("right", "left")[v % 2]
    sup = "left" if side == "right" else "right"
    elev = math.radians((-32.0, -14.0, 4.0)[v % 3] + rng.uniform(-4, 4))
    azim = math.radians(-lateral_sign(side) * rng.uniform(-6.0, 12.0))
    t_shift = 0.4 + 0.2 * rng.uniform(0, 1)
    t_lift = t_shift + 0.3
    t_apex = _snap(t_lift + 0.42 + 0.1 * rng.uniform(0, 1), fps)
    t_down = t_apex + 0.5
    t_end = t_down + 0.9
    t, plan, plants = _stationary(rig, t_end + 0.6, fps, {s: (lateral_sign(s) * 0.1, 0.0, -lateral_sign(s) * 0.08) for s in SIDES})
    stand = np.array([0.0, rig.stand_height - 0.02, 0.0])
    shifted = stand + np.array([lateral_sign(sup) * 0.06, -0.04, 0.0])
    leaned = shifted + np.array([0.0, -0.02, -0.04])
    root = _keys(t, [(0.0, stand), (t_shift, shifted), (t_lift, shifted), (t_apex, leaned), (t_down, shifted),
                     (t_end, stand)])
    pitch = _keys(t, [(t_lift, 0.0), (t_apex, -0.18), (t_down, 0.0)])[:, 0]
    _apply_root(plan, root, np.zeros(len(t)), pitch)
    plan.spine[:, 0] = _keys(t, [(t_lift, 0.0), (t_apex, 0.1), (t_down, 0.0)])[:, 0]
    guard = _keys(t, [(0.0, [0.07, 0.1, 0.2]), (t_shift, [0.6, 0.35, 1.7]), (t_down, [0.6, 0.35, 1.7]),
                      (t_end, [0.07, 0.1, 0.2])])
    for s in SIDES:
        plan.arms[s] = guard.copy()
    level_head(plan, pitch)
    i = round(t_apex * fps)
    target = _hip(rig, plan, side, i) + 0.88 * rig.leg * _dir(elev, azim)
    start = plants[side][0].ankle
    b = _pulse(t, t_lift, t_apex, t_down)
    chamber = np.array([0.0, 0.28, 0.12])
    ankle = start + b[:, None] * (target - start) + (4.0 * b * (1.0 - b))[:, None] * chamber
    w = ((t > t_lift) & (t < t_down)).astype(np.float64)
    override_foot(plan.feet[side], w, ankle, math.radians(25.0) * b)
    effector = ("Left" if side == "left" else "Right") + "Foot"
    targets = [{"name": "kick", "effector": effector, "t": t_apex, "local": target}]
    actions = [{"label": "shift", "t0": t_shift - 0.4, "t1": t_lift},
               {"label": "kick", "t0": t_lift, "t1": t_down, "apex": t_apex},
               {"label": "recover", "t0": t_down, "t1": t_end}]
    plants[side] = [replace(plants[side][0], t_off=t_lift), replace(plants[side][0], t_on=t_down)]
    params = {"side": side, "elevation_deg": math.degrees(elev), "azimuth_deg": math.degrees(azim),
              "target_height": float(target[1])}
    return ClipSpec(plan, actions, targets, [], plants, params)


def _hand_targets(rig: Rig, plan: Plan, fps: float,
                  strikes: list[tuple[str, float, float, float, np.ndarray, float]]) -> list[dict[str, Any]]:
    """Pull wrists onto targets: strikes are (side, t_start, t_apex, t_end, direction, hold); each
    target sits at 0.92 arm lengths from the shoulder at the apex frame. Sets plan.hands."""
    motion, _ = build_motion(rig, plan, fps)
    gpos, _ = forward_kinematics(motion)
    t = plan.t
    blend = {s: np.zeros(len(t)) for s in SIDES}
    goal = {s: np.zeros((len(t), 3)) for s in SIDES}
    out = []
    for side, t_a, t_apex, t_b, direction, hold in strikes:
        prefix = "Left" if side == "left" else "Right"
        i = round(t_apex * fps)
        target = gpos[i, rig.skeleton.index(prefix + "Arm")] + 0.92 * rig.arm * direction
        b = _pulse(t, t_a, t_apex, t_b, hold)
        m = (t >= t_a) & (t <= t_b)
        blend[side][m] = b[m]
        goal[side][m] = target
        out.append({"name": "strike", "effector": prefix + "Hand", "t": t_apex, "local": target})
    plan.hands = {s: (blend[s], goal[s]) for s in SIDES if np.any(blend[s] > 0)}
    return out


def _gen_punch(rig: Rig, v: int, rng: np.random.Generator, fps: float) -> ClipSpec:
    lead = ("left", "right")[v % 2]
    back = "right" if lead == "left" else "left"
    feet = {lead: (lateral_sign(lead) * 0.11, 0.14, 0.25), back: (lateral_sign(back) * 0.11, -0.14, 0.35)}
    n = 3
    t_first = 0.8 + 0.2 * rng.uniform(0, 1)
    gap = 0.65 + 0.1 * rng.uniform(0, 1)
    t_end = t_first + gap * (n - 1) + 1.0
    t, plan, plants = _stationary(rig, t_end, fps, feet)
    ready = np.array([0.0, rig.stand_height - 0.06, 0.0])
    plan.root_pos = ready + (0.01 * np.sin(2 * np.pi * 1.5 * t))[:, None] * UNIT_Y
    sides = [lead, back, lead] if v % 3 != 2 else [back, lead, back]
    elevs = rng.permutation(np.radians([6.0, -6.0, -18.0])) + np.radians(rng.uniform(-3, 3, n))
    twist = np.zeros(len(t))
    strikes = []
    for k, side in enumerate(sides):
        t_apex = _snap(t_first + k * gap, fps)
        t_a, t_b = t_apex - 0.14, t_apex + 0.26
        azim = -lateral_sign(side) * math.radians(8.0 + 6.0 * rng.uniform(0, 1))
        strikes.append((side, t_a, t_apex, t_b, _dir(float(elevs[k]), azim), 0.0))
        twist += -lateral_sign(side) * 0.3 * _pulse(t, t_a, t_apex, t_b)
    _apply_root(plan, plan.root_pos, 0.35 * twist, np.full(len(t), 0.08))
    plan.spine[:, 0] = 0.12
    plan.spine[:, 1] = 0.65 * twist
    for s in SIDES:
        plan.arms[s] = np.tile([0.55, 0.3, 2.0], (len(t), 1))
    level_head(plan, np.full(len(t), 0.08))
    plan.head[:, 1] = -twist
    targets = _hand_targets(rig, plan, fps, strikes)
    for tg in targets:
        tg["name"] = "punch"
    actions = [{"label": "guard", "t0": 0.0, "t1": strikes[0][1]}]
    actions += [{"label": "punch", "t0": a, "t1": b, "apex": ap, "side": sd} for sd, a, ap, b, _, _ in strikes]
    params = {"lead": lead, "punch_sides": sides, "elevations_deg": np.degrees(elevs)}
    return ClipSpec(plan, actions, targets, [], plants, params)


def _gen_reach(rig: Rig, v: int, rng: np.random.Generator, fps: float) -> ClipSpec:
    level = ("low", "mid", "high")[v % 3]
    side = ("right", "left")[int(rng.integers(0, 2))]
    t_a = 0.5 + 0.2 * rng.uniform(0, 1)
    t_apex = _snap(t_a + 0.9 + 0.2 * rng.uniform(0, 1), fps)
    hold = 0.3
    t_b = t_apex + hold + 0.9
    t, plan, plants = _stationary(rig, t_b + 0.7, fps, {s: (lateral_sign(s) * 0.11, 0.0, -lateral_sign(s) * 0.1) for s in SIDES})
    b = _pulse(t, t_a, t_apex, t_b, hold)
    pose = {"low": (0.3, 0.7, -0.26, -0.1, -70.0), "mid": (0.08, 0.25, -0.03, -0.02, -12.0),
            "high": (0.0, -0.1, 0.0, 0.0, 62.0)}[level]
    pelvis, spine, dy, dz, elev = pose
    stand = np.array([0.0, rig.stand_height - 0.02, 0.0])
    root = stand + b[:, None] * np.array([lateral_sign(side) * 0.03, dy, dz])
    yaw = -lateral_sign(side) * 0.15 * b
    _apply_root(plan, root, yaw, pelvis * b)
    plan.spine[:, 0] = spine * b
    plan.spine[:, 1] = -lateral_sign(side) * 0.2 * b
    other = "left" if side == "right" else "right"
    plan.arms[other][:, 0] += 0.3 * b
    level_head(plan, pelvis * b, 0.5)
    azim = -lateral_sign(side) * math.radians(rng.uniform(-15.0, 25.0))
    direction = _dir(math.radians(elev + rng.uniform(-5, 5)), azim)
    targets = _hand_targets(rig, plan, fps, [(side, t_a, t_apex, t_b, direction, hold)])
    targets[0]["name"] = f"reach_{level}"
    actions = [{"label": "stand", "t0": 0.0, "t1": t_a},
               {"label": "reach", "t0": t_a, "t1": t_b, "apex": t_apex, "hold_end": t_apex + hold},
               {"label": "stand", "t0": t_b, "t1": float(t[-1])}]
    params = {"level": level, "side": side, "target_height": float(targets[0]["local"][1])}
    return ClipSpec(plan, actions, targets, [], plants, params)


def _gen_sit(rig: Rig, v: int, rng: np.random.Generator, fps: float) -> ClipSpec:
    seat = (0.42, 0.47, 0.52)[v % 3] + 0.02 * rng.uniform(-1, 1)
    t1 = 0.5 + 0.3 * rng.uniform(0, 1)
    t2 = _snap(t1 + 1.3 + 0.2 * rng.uniform(0, 1), fps)
    t3 = t2 + 1.0 + 0.4 * rng.uniform(0, 1)
    t4 = t3 + 1.3 + 0.2 * rng.uniform(0, 1)
    t, plan, plants = _stationary(rig, t4 + 0.5, fps, {s: (lateral_sign(s) * 0.12, 0.05, -lateral_sign(s) * 0.1) for s in SIDES})
    stand = np.array([0.0, rig.stand_height - 0.015, 0.0])
    seated = np.array([0.0, seat + 0.1, -0.32])
    mid_down = np.array([0.0, 0.5 * (stand[1] + seated[1]) + 0.04, -0.2])
    mid_up = np.array([0.0, 0.5 * (stand[1] + seated[1]) + 0.02, -0.12])
    root = _keys(t, [(t1, stand), (0.5 * (t1 + t2), mid_down), (t2, seated), (t3, seated),
                     (0.5 * (t3 + t4), mid_up), (t4, stand)])
    lean = _keys(t, [(t1, 0.0), (0.5 * (t1 + t2), 0.55), (t2, 0.1), (t3, 0.1), (t3 + 0.45 * (t4 - t3), 0.7),
                     (t4, 0.0)])[:, 0]
    _apply_root(plan, root, np.zeros(len(t)), 0.5 * lean)
    plan.spine[:, 0] = 0.6 * lean
    seated_w = _keys(t, [(t1, 0.0), (t2, 1.0), (t3, 1.0), (t4, 0.0)])[:, 0]
    for s in SIDES:
        plan.arms[s][:, 0] += 0.5 * seated_w
        plan.arms[s][:, 2] += 0.5 * seated_w
    level_head(plan, 0.5 * lean, 0.6)
    actions = [{"label": "stand", "t0": 0.0, "t1": t1}, {"label": "sit_down", "t0": t1, "t1": t2},
               {"label": "seated", "t0": t2, "t1": t3}, {"label": "stand_up", "t0": t3, "t1": t4},
               {"label": "stand", "t0": t4, "t1": float(t[-1])}]
    targets = [{"name": "seat", "effector": "Hips", "t": t2, "local": seated}]
    return ClipSpec(plan, actions, targets, [], plants, {"seat_height": seat})


def _gen_idle(rig: Rig, v: int, rng: np.random.Generator, fps: float) -> ClipSpec:
    duration = 4.0 + rng.uniform(0, 1)
    w = 0.11 + 0.02 * rng.uniform(-1, 1)
    t, plan, plants = _stationary(rig, duration, fps, {s: (lateral_sign(s) * w, 0.02 * rng.uniform(-1, 1),
                                                           -lateral_sign(s) * 0.12) for s in SIDES})
    f_sway = rng.uniform(0.2, 0.35)
    f_breath = rng.uniform(0.22, 0.32)
    ph = rng.uniform(0, 2 * np.pi, 4)
    x = 0.035 * np.sin(2 * np.pi * f_sway * t + ph[0])
    y = rig.stand_height - 0.015 - 0.008 * (1 + np.sin(2 * np.pi * f_sway * 2 * t + ph[1])) \
        + 0.003 * np.sin(2 * np.pi * f_breath * t)
    root = np.stack([x, y, 0.01 * np.sin(2 * np.pi * 0.5 * f_sway * t + ph[2])], -1)
    _apply_root(plan, root, 0.05 * np.sin(2 * np.pi * 0.5 * f_sway * t + ph[3]), np.full(len(t), 0.03),
                -1.2 * x)
    plan.spine[:, 0] = 0.02 * np.sin(2 * np.pi * f_breath * t)
    plan.spine[:, 2] = 1.0 * x
    looks = np.sort(rng.uniform(0.5, duration - 0.5, 3))
    plan.head[:, 1] = _keys(t, [(k, rng.uniform(-0.5, 0.5)) for k in looks])[:, 0]
    for s in SIDES:
        plan.arms[s][:, 0] += 0.04 * np.sin(2 * np.pi * f_sway * t + ph[0] + lateral_sign(s))
    actions = [{"label": "idle", "t0": 0.0, "t1": float(t[-1])}]
    return ClipSpec(plan, actions, [], [], plants, {"sway_hz": f_sway, "breath_hz": f_breath})


# --------------------------------------------------------------------------------------------------
# hop: one-legged hops with exact ballistic flights


def _ballistic_root(t: np.ndarray, knots: list[tuple[float, np.ndarray, np.ndarray]],
                    flights: list[tuple[float, np.ndarray, np.ndarray, float]]) -> np.ndarray:
    """Hermite through (time, position, velocity) knots, exactly ballistic on each (t0, p0, v0, t1)."""
    out = hermite(t, [k[0] for k in knots], np.array([k[1] for k in knots]), np.array([k[2] for k in knots]))
    for t0, p0, v0, t1 in flights:
        m = (t >= t0) & (t <= t1)
        dt = (t[m] - t0)[:, None]
        out[m] = p0 + v0 * dt - 0.5 * G * dt * dt * UNIT_Y
    return out


def _gen_hop(rig: Rig, v: int, rng: np.random.Generator, fps: float) -> ClipSpec:
    sup = ("left", "right")[v % 2]
    free = "right" if sup == "left" else "left"
    n_hops = 3
    vh = (0.0, 0.45, 0.8)[v % 3] + 0.05 * rng.uniform(0, 1)
    apex = 0.09 + 0.04 * rng.uniform(0, 1)
    vy = math.sqrt(2.0 * G * apex)
    ts = 0.3
    heel = math.radians(25.0)
    width = 0.2
    xs = lateral_sign(sup) * 0.07
    ready_y = rig.stand_height - 0.03
    low_y = ready_y - 0.12
    t_lift = 0.4 + 0.2 * rng.uniform(0, 1)
    t_b = t_lift + 0.6
    sup_plant = Plant(t_on=-1.0, t_off=100.0, ankle=np.array([lateral_sign(sup) * width / 2, rig.ankle_height, 0.0]),
                      yaw=-lateral_sign(sup) * math.radians(5.0))
    zero = np.zeros(3)
    knots = [(0.0, np.array([0.0, ready_y + 0.01, 0.0]), zero), (t_b - 0.25, np.array([xs, ready_y, 0.0]), zero),
             (t_b, np.array([xs, low_y, 0.0]), zero)]
    plants_sup: list[Plant] = []
    flights: list[tuple[float, np.ndarray, np.ndarray, float]] = []
    actions: list[dict[str, Any]] = [{"label": "lift_leg", "t0": t_lift, "t1": t_b - 0.25}]
    pitch = math.radians(6.0)
    rot = qypr(0.0, pitch)
    cur, t_bottom, dz = sup_plant, t_b, vh * ts / 4.0
    for k in range(n_hops):
        t0 = t_bottom + ts / 2.0
        take = replace(cur, t_off=t0, t_heel=t0 - 0.1, heel_pitch=heel)
        plants_sup.append(take)
        z0 = knots[-1][1][2] + dz
        y0 = root_height_for(rig, np.array([xs, 0.0, z0]), rot, {sup: take.pivot_ankle(rig, np.array([heel]))[0]},
                              0.96 * rig.leg)
        ahead = vh * ts / 2.0
        rel = {sup: np.array([lateral_sign(sup) * width / 2 - xs, rig.ankle_height, ahead])}
        y1 = root_height_for(rig, np.zeros(3), rot, rel, 0.95 * rig.leg)
        tf = (vy + math.sqrt(vy * vy + 2.0 * G * (y0 - y1))) / G
        p0, v0 = np.array([xs, y0, z0]), np.array([0.0, vy, vh])
        t1 = t0 + tf
        p1, v1 = p0 + v0 * tf - 0.5 * G * tf * tf * UNIT_Y, v0 - G * tf * UNIT_Y
        knots += [(t0, p0, v0), (t1, p1, v1)]
        flights.append((t0, p0, v0, t1))
        actions.append({"label": "hop", "t0": t_bottom, "t1": t1})
        cur = Plant(t_on=t1, t_off=100.0, ankle=np.array([lateral_sign(sup) * width / 2, rig.ankle_height, p1[2] + ahead]),
                    yaw=sup_plant.yaw)
        if k + 1 < n_hops:
            t_bottom = t1 + ts / 2.0
            knots.append((t_bottom, np.array([xs, low_y, p1[2] + ahead]), np.array([0.0, 0.0, vh])))
            dz = ahead
    plants_sup.append(cur)
    t_abs = 0.25
    depth = max(0.12, abs(v1[1]) * t_abs / 3.0)
    t_a = t1 + t_abs
    knots.append((t_a, np.array([xs, y1 - depth, p1[2] + 0.4 * vh * t_abs]), zero))
    t_rec = t_a + 0.5
    knots.append((t_rec, np.array([xs, ready_y, cur.ankle[2]]), zero))
    t_down = t_rec + 0.4
    knots.append((t_down + 0.3, np.array([0.0, ready_y + 0.01, cur.ankle[2]]), zero))
    t_end = t_down + 0.7
    actions += [{"label": "landing", "t0": t1, "t1": t_a}, {"label": "recover", "t0": t_a, "t1": t_rec},
                {"label": "lower_leg", "t0": t_rec, "t1": t_down}]
    t = frame_times(t_end, fps)
    free_plants = [Plant(t_on=-1.0, t_off=t_lift, ankle=np.array([lateral_sign(free) * width / 2, rig.ankle_height, 0.0]),
                         yaw=-lateral_sign(free) * math.radians(5.0)),
                   Plant(t_on=t_down, t_off=t_end + 1.0, yaw=-lateral_sign(free) * math.radians(5.0),
                         ankle=np.array([lateral_sign(free) * width / 2, rig.ankle_height, cur.ankle[2]]))]
    plants = {sup: plants_sup, free: free_plants}
    feet = {s: foot_track(rig, t, plants[s], 0.05) for s in SIDES}
    plan = neutral_plan(rig, t, feet)
    plan.root_pos = _ballistic_root(t, knots, flights)
    carried = plan.root_pos + np.array([lateral_sign(free) * 0.1 - xs, -0.52, -0.22])
    w = smooth((t - t_lift) / (t_b - 0.25 - t_lift)) * (1.0 - smooth((t - t_rec) / (t_down - t_rec)))
    override_foot(plan.feet[free], w, carried, 0.3 * w)
    for fl in flights:  # the support foot follows the root in the air
        t0, p0, _, t1 = fl
        i0 = next(p for p in plants_sup if abs(p.t_off - t0) < 1e-12)
        i1 = next(p for p in plants_sup if abs(p.t_on - t1) < 1e-12)
        r0 = i0.pivot_ankle(rig, np.array([heel]))[0] - p0
        p1 = _ballistic_root(np.array([t1]), knots, flights)[0]
        r1 = i1.ankle - p1
        rel = hermite(t, [t0, 0.5 * (t0 + t1), t1], np.array([r0, 0.5 * (r0 + r1) + 0.08 * UNIT_Y, r1]))
        m = ((t > t0) & (t < t1)).astype(np.float64)
        override_foot(plan.feet[sup], m, plan.root_pos + rel)
    plan.root_rot = qypr(np.zeros(len(t)), np.full(len(t), pitch))
    plan.spine[:, 0] = 0.08
    lift = smooth((t - t_lift) / 0.4) * (1.0 - smooth((t - t_rec) / 0.5))
    for s in SIDES:
        plan.arms[s][:, 0] += lift * (0.25 + 0.15 * np.sin(2 * np.pi * t / (ts + 0.35)))
        plan.arms[s][:, 1] += 0.35 * lift
        plan.arms[s][:, 2] += 0.6 * lift
    level_head(plan, np.full(len(t), pitch))
    params = {"support": sup, "hops": n_hops, "horizontal_speed": vh, "apex_height": apex,
              "flight_times": [fl[3] - fl[0] for fl in flights]}
    return ClipSpec(plan, actions, [], [(fl[0], fl[3]) for fl in flights], plants, params)




GENERATORS: dict[str, Callable[[Rig, int, np.random.Generator, float], ClipSpec]] = {
    "walk": _gen_walk,
    "run": _gen_run,
    "jump": _gen_jump,
    "kick": _gen_kick,
    "punch": _gen_punch,
    "reach": _gen_reach,
    "sit": _gen_sit,
    "hop": _gen_hop,
    "idle": _gen_idle,
}
