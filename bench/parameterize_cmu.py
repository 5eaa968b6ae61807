"""Parameterized motion on real data (KG04 §4.4 on CMU subject 16): a walk parameterized by its
final root position and a forward jump by its landing position, each example registered by
data-driven key times (walks: two left touchdowns a stride apart; jumps: take-off and landing of
the detected flight). Prints leave-one-out errors and foot skate of blends against the examples.

Run from the repo root: ``python -m bench.parameterize_cmu`` (needs the mocap folder; see
``store.datasets.mocap_root``).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from motionweb.store.datasets import mocap_root
from motionweb.store.formats import read_motion
from motionweb.store.kinematics import airborne_intervals, forward_kinematics
from motionweb.tasks.blend import (
    BlendParams,
    blend,
    detect_plants,
    foot_skate,
    keytime_registration,
    leg_chains,
    metric_skeleton,
    registered_examples,
    runs,
)
from motionweb.tasks.parameterize import (
    FinalRoot,
    ParameterizeParams,
    build_space,
    example_params,
    leave_one_out,
)

CFG = BlendParams()
WALKS = (11, 12, 13, 14, 15, 16, 21, 22, 23, 24, 25, 26, 31, 32, 47, 58)
JUMPS = (1, 2, 3, 4, 5, 6, 7, 9, 10)


def ankles(m, f0: int = 0, f1: int | None = None) -> np.ndarray:
    sk = metric_skeleton(m)
    legs = leg_chains(sk)
    f1 = m.n_frames - 1 if f1 is None else f1
    g, _ = forward_kinematics(replace(m, skeleton=sk, root_positions=m.root_positions[f0:f1 + 1] * m.metres(),
                                      rotations=m.rotations[f0:f1 + 1]))
    return g[:, [legs["left"][2], legs["right"][2]]]


def walk_keys(m):
    pl = detect_plants(ankles(m), m.fps, CFG)
    downs = [a / m.fps for a, _ in runs(pl[:, 0]) if a > 0]
    later = [t for t in downs if downs and t >= downs[0] + 0.6]
    return np.array([downs[0], later[0]]) if later else None


def jump_keys(m):
    air = airborne_intervals(m)
    if not air:
        return None
    a, b = max(air, key=lambda ab: ab[1] - ab[0])
    k = np.array([a / m.fps - 0.7, a / m.fps, b / m.fps, b / m.fps + 0.6])
    return k if k[0] >= 0 and k[-1] <= m.duration else None


def report(label: str, trials, keys_of) -> None:
    root = mocap_root() / "cmu" / "asf_amc" / "16"
    motions, keys, skates = [], [], []
    for t in trials:
        m = read_motion(root / f"16_{t:02d}.amc")
        k = keys_of(m)
        if k is None:
            continue
        motions.append(m)
        keys.append(k)
        ank = ankles(m, int(k[0] * m.fps), int(k[-1] * m.fps))
        skates.append(foot_skate(ank, detect_plants(ank, m.fps, CFG), m.fps))
    ex = registered_examples(motions, keytime_registration(motions, keys), cfg=CFG)
    fn = FinalRoot()
    p = example_params(fn, ex)
    loo = leave_one_out(fn, ex, ParameterizeParams())
    sp = build_space(fn, ex, ParameterizeParams())
    rng = np.random.default_rng(0)
    res = []
    for tgt in sp.params[rng.choice(np.arange(ex.n, len(sp.params)), 10)] + 0.005:
        s = sp.synthesize(tgt)
        r = blend(ex, s.weights, fps=motions[0].fps, cfg=CFG)
        res.append((s.error, r.skate_raw, r.skate, r.ik_miss))
    res = np.array(res)
    print(f"\n{label}: {ex.n} examples, final root (x, z) from {p.min(0).round(2)} to {p.max(0).round(2)} m")
    print(f"  leave-one-out error (cm): median {100 * np.median(loo):.1f}, max {100 * loo.max():.1f}  "
          f"[{', '.join(f'{100 * v:.1f}' for v in loo)}]")
    print(f"  {len(sp.params)} samples; 10 targets 0.5 cm off samples: error mean {100 * res[:, 0].mean():.2f} cm, "
          f"max {100 * res[:, 0].max():.2f}")
    print(f"  foot skate (cm/s, planted frames): examples mean {np.mean(skates):.2f} ({min(skates):.2f}-{max(skates):.2f}); "
          f"blends before IK {res[:, 1].mean():.2f}, after {res[:, 2].mean():.2f} (max {res[:, 2].max():.2f}); "
          f"worst IK miss {1000 * res[:, 3].max():.1f} mm")


def main() -> None:
    report("walk (subject 16 walks and veers, one stride)", WALKS, walk_keys)
    report("jump (subject 16 jumps, crouch to 0.6 s after landing)", JUMPS, jump_keys)


if __name__ == "__main__":
    main()
