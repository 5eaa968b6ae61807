"""Flight-keyed registration of jumps (KG04 §4.1 with KG03's constraint matching; design §6).

A jump's examples must agree where the body leaves and meets the ground: take-off and landing are
hard constraints a blend has to line up, while the frame-distance registration of §4.1 only
follows the web paths the search walked. On real jumps those paths are often short or
time-compressed (a 20-frame match of a 43-frame query: the search accepts slopes up to k, and
the crouch, the flight and the landing look alike at different speeds), so some matches hold no
flight at all and others cover the jump squeezed to half its duration.

Choice made here (used when the query holds exactly one flight phase; ``ParameterizeParams.registration``):

* the query's flight (take-off t0, landing t1, from :func:`store.kinematics.airborne_intervals`
  on the whole clip) and its lead t0 − start and trail end − t1 are measured;
* each match (search node) is assigned the flight of its clip that overlaps its segment most; a
  match overlapping no flight (a crouch, a walk away) is dropped, and of several matches of one
  flight the one nearest the query in the match graph is kept;
* the example is the span [take-off − lead, landing + trail] of its clip (the query's full span,
  so partial matches are extended and over-long ones trimmed); one that would run past its clip
  is dropped;
* the registration maps the four key times (start, take-off, landing, end) of the query onto the
  example's, linearly between them (:func:`tasks.blend.keytime_registration`).

Cost: one FK of every clip with a match (O(F·J) each), then O(U·N).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from motionweb.store.kinematics import airborne_intervals
from motionweb.store.motion import Motion
from motionweb.tasks.blend import keytime_registration
from motionweb.tasks.matchgraph import Segment
from motionweb.tasks.register import Registration


def flights(motion: Motion) -> list[tuple[float, float]]:
    """(take-off, landing) seconds of every flight phase of a clip (``airborne_intervals``)."""
    return [(a / motion.fps, b / motion.fps) for a, b in airborne_intervals(motion)]


def query_flight(motion: Motion, segment: Segment, rate: float) -> tuple[float, float] | None:
    """The one flight lying strictly inside the query ``segment`` (frames at ``rate``), or None
    when the query holds no flight or several (a run of strides: the web registration fits)."""
    s0, s1 = segment.start / rate, segment.end / rate
    inside = [(a, b) for a, b in flights(motion) if s0 < a and b < s1]
    return inside[0] if len(inside) == 1 else None


@dataclass
class FlightExamples:
    """The examples kept: ``kept`` indices into the given segments (the query first), the
    registration over them, and why each other segment was dropped (``dropped``: index ->
    reason)."""

    registration: Registration
    kept: list[int]
    dropped: dict[int, str]


def flight_registration(motions: Mapping[str, Motion], segments: Sequence[Segment], distances: Sequence[float],
                        rate: float) -> FlightExamples:
    """Flight-keyed examples from search matches (see the module docstring).

    ``segments[0]`` is the query, the others the search's matches in order of graph distance
    (``distances``), frames at ``rate``; ``motions[clip]`` the clips. ValueError when the query
    holds no single flight.
    """
    q = segments[0]
    qm = motions[q.clip]
    fl = query_flight(qm, q, rate)
    if fl is None:
        raise ValueError(f"the query {q.clip} {q.start / rate:g}-{q.end / rate:g} s holds no single flight phase: "
                         "flight-keyed registration needs a jump (use parameterize.registration: web)")
    lead, trail = fl[0] - q.start / rate, q.end / rate - fl[1]
    keys = [np.array([q.start / rate, fl[0], fl[1], q.end / rate])]
    kept, dropped, seen = [0], {}, {(q.clip, fl)}
    cache: dict[str, list[tuple[float, float]]] = {}
    for i in range(1, len(segments)):
        s = segments[i]
        m = motions[s.clip]
        if s.clip not in cache:
            cache[s.clip] = flights(m)
        a, b = s.start / rate, s.end / rate
        over = [(min(b, f1) - max(a, f0), f1 - f0, (f0, f1)) for f0, f1 in cache[s.clip]]
        over = [o for o in over if o[0] > 0]
        if not over:
            dropped[i] = "no flight phase in the match"
            continue
        f0, f1 = max(over)[2]
        if (s.clip, (f0, f1)) in seen:
            dropped[i] = "its flight is already an example"
            continue
        k = np.array([f0 - lead, f0, f1, f1 + trail])
        if k[0] < 0 or k[-1] > (m.n_frames - 1) / m.fps:
            dropped[i] = f"the query's span around its flight runs past the clip ({m.duration:.2f} s)"
            continue
        seen.add((s.clip, (f0, f1)))
        kept.append(i)
        keys.append(k)
    ms = [motions[segments[i].clip] for i in kept]
    reg = keytime_registration(ms, keys, rate)
    segs = [Segment(segments[i].clip, s.start, s.end) for i, s in zip(kept, reg.segments, strict=True)]
    reg = Registration(reg.rate, kept, segs, [-1] + [0] * (len(kept) - 1),
                       np.asarray([distances[i] for i in kept], np.float64), reg.frames, [])
    return FlightExamples(reg, kept, dropped)
