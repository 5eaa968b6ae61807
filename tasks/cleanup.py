"""Foot-slide cleanup: detected foot plants held still by the leg IK of blending (issue 26;
design "Exports").

The plants are those blending detects (:func:`tasks.blend.detect_plants`: ankle within
``plant_height`` of its lowest point and slower than ``plant_speed``, runs of at least
``plant_min_s``), and each planted run is held at its mean ankle position by the same analytic
two-bone leg IK, eased in and out over ``ease_s`` (:func:`tasks.blend.hold_plants`; KG03
constraint matching), except that a run is held at the point nearest its mean ankle position that
the leg reaches on every frame of the run (:func:`reachable_hold`): a walk's heel strike and toe
off straighten the knee, and a mean the leg cannot reach would leave the ankle sliding by the
IK's miss; and two plants of one foot less than ``ease_s`` apart are held as one (the foot
barely lifts between them; held apart, the easing of one would reach into the other), and each
held run starts one frame before the detected plant and ends one after, so the foot is still on
every detected frame, its central-difference speed included. Parameters are the config's ``blend`` section (:class:`BlendParams`):
one set of plant thresholds for blends and cleanups. Only the hip, knee and ankle rotations of
the legs change, so every joint outside the legs keeps its world position exactly.

Foot skate (:func:`tasks.blend.foot_skate`): the mean horizontal ankle speed over the planted
frames, cm/s, before and after, on the same plants. Positions in metres, Y up. O(F) for the two
legs (FK along the root-to-ankle paths only, compiled IK).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from motionweb.store.kinematics import axis_index, forward_kinematics_of
from motionweb.store.motion import Motion
from motionweb.tasks.blend import SIDES, BlendParams, detect_plants, foot_skate, hold_plants, leg_chains, runs

#: a held ankle stays within this fraction of the leg's length (thigh + shank) of the hip
REACH = 0.998


@dataclass(frozen=True)
class CleanupResult:
    """The cleaned motion, its plants (F, 2) bool (left, right), foot skate before and after
    (cm/s over planted frames), the worst IK miss (m) and the leg chains (hip, knee, ankle)."""

    motion: Motion
    plants: np.ndarray
    skate_before: float
    skate_after: float
    miss_m: float
    legs: dict[str, tuple[int, int, int]]


def ankle_paths(motion: Motion, legs: dict[str, tuple[int, int, int]]) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """Ankle positions (F, 2, 3) in metres (left, right) and the FK of the root-to-ankle paths
    (file units) it came from."""
    feet = [legs[s][2] for s in SIDES]
    fk = forward_kinematics_of(motion, feet)
    return fk[0][:, feet] * motion.metres(), fk


def reachable_hold(ankles: np.ndarray, hips: np.ndarray, reach: float, iterations: int = 200) -> np.ndarray:
    """The point (3,) held through one planted run: the mean of ``ankles`` (R, 3) moved into the
    balls of radius ``reach`` around ``hips`` (R, 3) (the places the ankle reaches on each frame)
    by repeated projection onto the ball it is furthest outside of (cyclic projections onto
    convex sets converge to a point of their intersection); the mean itself when it is inside
    them all, the last iterate when they do not meet."""
    c = ankles.mean(axis=0)
    for _ in range(iterations):
        d = c - hips
        dist = np.linalg.norm(d, axis=1)
        k = int(np.argmax(dist - reach))
        if dist[k] <= reach:
            break
        c = hips[k] + d[k] * (reach / dist[k])
    return c


def close_gaps(plants: np.ndarray, shortest: int) -> np.ndarray:
    """(F, 2) plants with every gap of fewer than ``shortest`` frames between two planted runs
    of one foot filled."""
    out = plants.copy()
    for k in range(plants.shape[1]):
        for a, b in runs(~plants[:, k]):
            if a > 0 and b < len(plants) - 1 and b - a + 1 < shortest:
                out[a:b + 1, k] = True
    return out


def widen(plants: np.ndarray, frames: int = 1) -> np.ndarray:
    """(F, 2) plants with every planted run grown by ``frames`` on both sides."""
    out = plants.copy()
    for k in range(plants.shape[1]):
        for a, b in runs(plants[:, k]):
            out[max(0, a - frames):b + 1 + frames, k] = True
    return out


def plant_holds(motion: Motion, legs: dict[str, tuple[int, int, int]], plants: np.ndarray,
                fk: tuple[np.ndarray, np.ndarray]) -> dict[str, np.ndarray]:
    """Per side (F, 3) the point each planted run is held at (:func:`reachable_hold`, file
    units); ``fk`` = global positions and rotations of at least the root-to-ankle paths."""
    out = {}
    off = motion.skeleton.offsets
    for k, side in enumerate(SIDES):
        hip, knee, ankle = legs[side]
        reach = REACH * (np.linalg.norm(off[knee]) + np.linalg.norm(off[ankle]))
        holds = fk[0][:, ankle].copy()
        for a, b in runs(plants[:, k]):
            holds[a:b + 1] = reachable_hold(fk[0][a:b + 1, ankle], fk[0][a:b + 1, hip], reach)
        out[side] = holds
    return out


def cleanup(motion: Motion, params: BlendParams | None = None, up: str = "y") -> CleanupResult:
    """Hold the motion's detected foot plants (see the module's docstring). ValueError naming
    the clip for a motion that is not Y up, has no known length unit, or whose ankles are not
    found by name (``blend.feet`` names them)."""
    params = params or BlendParams()
    if axis_index(up) != 1:
        raise ValueError(f"{motion.name or 'motion'}: foot-slide cleanup detects plants in Y-up motions "
                         f"(corpus.up_axis is {up!r})")
    legs = leg_chains(motion.skeleton, params.feet)
    ankles, fk = ankle_paths(motion, legs)
    plants = detect_plants(ankles, motion.fps, params)
    before = foot_skate(ankles, plants, motion.fps)
    if not plants.any():
        return CleanupResult(motion, plants, before, before, 0.0, legs)
    held_plants = close_gaps(widen(plants), max(1, round(params.ease_s * motion.fps)) + 1)
    held, miss = hold_plants(motion, legs, held_plants, params, fk, holds=plant_holds(motion, legs, held_plants, fk))
    after = foot_skate(ankle_paths(held, legs)[0], plants, motion.fps)
    return CleanupResult(held, plants, before, after, miss * motion.metres(), legs)
