"""Flight-keyed examples of jumps (tasks/flights.py) against the demo's known flights and CMU jumps."""

from __future__ import annotations

import numpy as np
import pytest
from motionweb.store.demo.corpus import generate_clip
from motionweb.store.formats import read_motion
from motionweb.tasks.blend import registered_examples
from motionweb.tasks.flights import flight_registration, flights, query_flight
from motionweb.tasks.matchgraph import Segment
from motionweb.tasks.parameterize import FinalRoot, ParameterizeParams, leave_one_out

RATE = 30.0


def seg(clip: str, a_s: float, b_s: float) -> Segment:
    return Segment(clip, round(a_s * RATE), round(b_s * RATE))


@pytest.fixture(scope="module")
def jumps():
    """Five demo jumps: clip name -> (motion, truth flight (take-off, landing) seconds)."""
    out = {}
    for v in range(5):
        m, t = generate_clip("jump", v, 7)
        f = t["flight"][0]
        out[m.name] = (m, (f["start_s"], f["end_s"]))
    return out


def test_detected_flights_are_the_demo_truth(jumps) -> None:
    for m, (t0, t1) in jumps.values():
        (f0, f1), = flights(m)
        assert f0 == pytest.approx(t0, abs=2.5 / m.fps) and f1 == pytest.approx(t1, abs=2.5 / m.fps)


def test_partial_matches_become_full_span_examples_keyed_by_their_flights(jumps) -> None:
    names = list(jumps)
    q_m, (q0, q1) = jumps[names[0]]
    fq = flights(q_m)[0]
    query = seg(names[0], q0 - 0.5, q1 + 0.4)
    assert query_flight(q_m, query, RATE) == fq
    f1 = flights(jumps[names[1]][0])[0]
    f2 = flights(jumps[names[2]][0])[0]
    segments = [query,
                seg(names[1], f1[0] - 0.3, f1[1] - 0.1),  # partial: crouch end and most of the flight
                seg(names[2], f2[0] + 0.1, f2[1] + 0.9),  # partial, shifted later: the landing and beyond
                seg(names[3], 0.0, 0.3),                   # standing only: no flight
                seg(names[1], f1[0], f1[1] + 0.2),         # the same flight again, farther in the graph
                seg(names[4], 0.05, 0.5)]                  # no flight either
    fx = flight_registration({n: m for n, (m, _) in jumps.items()}, segments, np.arange(6) * 0.1, RATE)
    assert fx.kept == [0, 1, 2]
    assert set(fx.dropped) == {3, 4, 5} and "already an example" in fx.dropped[4]
    reg = fx.registration
    lead, trail = fq[0] - query.start / RATE, query.end / RATE - fq[1]
    u = reg.u
    for c, f in enumerate((fq, f1, f2)):
        s = reg.frames[:, c] / RATE
        # take-off and landing of the query fall on each example's take-off and landing (the curve is
        # sampled at whole query frames, so between samples it cuts the corner: half a frame)
        assert np.interp(fq[0] * RATE, u, s) == pytest.approx(f[0], abs=0.5 / RATE)
        assert np.interp(fq[1] * RATE, u, s) == pytest.approx(f[1], abs=0.5 / RATE)
        # the example spans the query's lead and trail around its own flight (to whole frames: segments)
        assert s[0] == pytest.approx(f[0] - lead, abs=1 / RATE) and s[-1] == pytest.approx(f[1] + trail, abs=1 / RATE)
        assert np.all(np.diff(s) > 0)
    assert reg.segments[1].clip == names[1] and reg.nodes == [0, 1, 2] and reg.parents == [-1, 0, 0]
    np.testing.assert_allclose(reg.distances, [0.0, 0.1, 0.2])


def test_queries_without_one_flight_are_not_flight_keyed(jumps) -> None:
    walk, _ = generate_clip("walk", 0, 7)
    assert query_flight(walk, seg(walk.name, 0.5, 2.5), RATE) is None
    m, (t0, t1) = next(iter(jumps.values()))
    assert query_flight(m, seg(m.name, 0.0, t0 + 0.1), RATE) is None  # the flight runs past the query's end
    with pytest.raises(ValueError, match="no single flight phase"):
        flight_registration({m.name: m}, [seg(m.name, 0.0, 0.5)], [0.0], RATE)


def test_cmu_forward_jumps_keyed_by_flight_give_a_landing_space(cmu_dir) -> None:
    """Real jumps (CMU subject 16) as the search leaves them: short and shifted matches of the
    query 16_07 1.5-2.9 s; flight-keyed, their landings span a space that reproduces each
    left-out landing within a few centimetres."""
    root = cmu_dir / "asf_amc" / "16"
    trials = ("16_07", "16_05", "16_06", "16_09", "16_10", "16_01", "16_02")
    motions = {t: read_motion(root / f"{t}.amc") for t in trials}
    segments = [Segment("16_07", 45, 87), Segment("16_05", 40, 63), Segment("16_06", 68, 87),
                Segment("16_09", 80, 98), Segment("16_10", 54, 96), Segment("16_01", 30, 50),
                Segment("16_02", 44, 84), Segment("16_07", 0, 14)]
    fx = flight_registration(motions, segments, np.linspace(0, 1, len(segments)), RATE)
    assert fx.kept == list(range(7)) and 7 in fx.dropped
    ex = registered_examples([motions[s.clip] for s in fx.registration.segments], fx.registration)
    loo = leave_one_out(FinalRoot(), ex, ParameterizeParams(samples=300))
    assert np.median(loo) < 0.05, loo
