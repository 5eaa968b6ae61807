"""HDP07 §4.1 on the paper's kind of data: subject 16's CMU jumps (skipped without the data).

Each jump, its own reference, compressed to 50% and 60% and expanded to 150%: the flight phase
(both feet off the clip's floor) keeps its speed within 10% while the ground phases absorb the
change; the linear warp, for contrast, scales the flight like everything else.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
from motionweb.store.formats import read_motion
from motionweb.store.kinematics import airborne_intervals, resample
from motionweb.tasks.guided_warp import guided_warp, linear_warp, playback_speed


@pytest.fixture(scope="module")
def jumps(cmu_dir: Path) -> list[Path]:
    with open(cmu_dir / "manifest.csv", newline="") as fh:
        rows = [r for r in csv.DictReader(fh) if r["category"] == "jump" and r["path"].startswith("asf_amc/16/")]
    return [cmu_dir / r["path"] for r in rows]


def test_kinematic_flight_of_each_jump_is_a_plausible_ballistic_phase(jumps: list[Path]) -> None:
    assert len(jumps) >= 5
    for path in jumps:
        m = resample(read_motion(path), 30.0)
        f0, f1 = max(airborne_intervals(m), key=lambda r: r[1] - r[0])
        assert 0.2 <= (f1 - f0 + 1) / m.fps <= 0.8, path.name  # a human jump's flight
        assert 0 < f0 and f1 < m.n_frames - 1, path.name  # ground phases before and after


@pytest.mark.parametrize("frac", [0.5, 0.6, 1.5])
def test_guided_warp_preserves_the_flight_of_every_subject16_jump(jumps: list[Path], frac: float) -> None:
    for path in jumps:
        m = resample(read_motion(path), 30.0)
        f0, f1 = max(airborne_intervals(m), key=lambda r: r[1] - r[0])
        n = m.n_frames
        n_out = round(frac * (n - 1)) + 1
        r = guided_warp(m, n_out=n_out, resample_motion=False)
        lin = linear_warp(m, n_out, resample_motion=False)
        flight = playback_speed(r.times, f0, f1)
        assert abs(flight - 1.0) <= 0.10, (path.name, frac, flight)
        assert abs(playback_speed(lin.times, f0, f1) - (n - 1) / (n_out - 1)) < 0.05  # linear scales it
        ground = (f0 + (n - 1 - f1)) / (np.interp(f0, r.times, np.arange(n_out))
                                        + (n_out - 1 - np.interp(f1, r.times, np.arange(n_out))))
        # the ground phases absorb the whole change: faster than linear when compressing, slower expanding
        if frac < 1:
            assert ground > (n - 1) / (n_out - 1), (path.name, frac, ground)
        else:
            assert ground < (n - 1) / (n_out - 1), (path.name, frac, ground)
