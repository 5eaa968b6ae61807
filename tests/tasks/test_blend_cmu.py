"""Blending and a parameterized walk on real data: CMU subject 16's straight walks, registered by
their detected left-foot touchdowns (a data-driven ground truth that needs no index)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from motionweb.store.formats import read_motion
from motionweb.store.kinematics import forward_kinematics
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

WALKS = tuple(f"16_{t}" for t in (11, 12, 13, 14, 15, 16, 21, 22, 23, 24, 25, 26, 31, 32, 47, 58))  # walks, veers


@pytest.fixture(scope="module")
def walks(cmu_dir: Path):
    cfg = BlendParams()
    motions, keys, skates = [], [], []
    for name in WALKS:
        path = cmu_dir / "asf_amc" / "16" / f"{name}.amc"
        if not path.is_file():
            pytest.skip(f"{path} not found")
        m = read_motion(path)
        sk = metric_skeleton(m)
        legs = leg_chains(sk)
        g, _ = forward_kinematics(replace(m, skeleton=sk, root_positions=m.root_positions * m.metres()))
        ank = g[:, [legs["left"][2], legs["right"][2]]]
        pl = detect_plants(ank, m.fps, cfg)
        downs = [a / m.fps for a, _ in runs(pl[:, 0]) if a > 0]
        on = [t for t in downs if t >= downs[0] + 0.6][:1] if downs else []
        on = [downs[0], *on]  # two left touchdowns a stride apart (≥ 0.6 s)
        if len(on) == 2:
            motions.append(m)
            keys.append(np.array(on))
            skates.append(foot_skate(ank, pl, m.fps))
    assert len(motions) >= 12
    return motions, keys, skates


def test_cmu_walk_space_leave_one_out_and_foot_skate(walks) -> None:
    motions, keys, skates = walks
    ex = registered_examples(motions, keytime_registration(motions, keys))
    fn = FinalRoot()
    p = example_params(fn, ex)
    assert np.all(p[:, 1] > 0.6)  # a stride forward, in the start-heading frame
    loo = leave_one_out(fn, ex, ParameterizeParams(samples=500))
    assert np.median(loo) < 0.05, loo
    sp = build_space(fn, ex, ParameterizeParams(samples=500))
    target = sp.params[ex.n + 3]
    s = sp.synthesize(target)
    assert s.error < 0.02
    r = blend(ex, s.weights, fps=motions[0].fps)
    assert r.skate <= 1.5 * np.mean(skates), (r.skate, skates)
    assert r.ik_miss < 0.03
