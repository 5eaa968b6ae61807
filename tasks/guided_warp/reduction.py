"""Reduction of every warp to compression: expansion by upsampling, backward by reversal, keytimes as path constraints (HDP07 §3.1)."""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

#: an (input frame, output frame) pair the warp must pass through
Keytime = tuple[float, float]


@dataclass(frozen=True)
class Reduction:
    """How a warp request is reduced to a compression (HDP07 §3.1).

    Attributes:
        upsample: integer factor u; working frame w is original frame w / u (or reversed).
        n: working input frame count, u (n0 - 1) + 1.
        m: output frame count (None: unconstrained).
        keys: working keytimes (input frame, output frame), endpoints included, both increasing
            (empty for an unconstrained warp).
        backward: whether working frame w is original frame (n0 - 1) - w / u.
    """

    upsample: int
    n: int
    m: int | None
    keys: tuple[tuple[int, int], ...]
    backward: bool

    def to_source(self, working: np.ndarray, n0: int) -> np.ndarray:
        """Working frames -> original input frames."""
        t = np.asarray(working, dtype=np.float64) / self.upsample
        return (n0 - 1) - t if self.backward else t


# Reduction to compression (HDP07 §3.1)


def reduce_to_compression(n0: int, m: int | None, keytimes: Sequence[Keytime] = (), skip: int = 8,
                          backward: bool = False) -> Reduction:
    """Choose the upsampling factor and working keytimes that make a request a compression.

    ``keytimes`` are intermediate (input frame, output frame) pairs in original frames (fractional
    values are rounded to the working grid). Forward warps need both coordinates strictly increasing
    and inside the clip; backward warps need the input frames strictly decreasing. Raises ValueError
    naming the violated constraint; nothing is clamped.
    """
    if skip < 1 or skip > 127:
        raise ValueError(f"skip must be in 1..127, got {skip}")
    if n0 < 2:
        raise ValueError(f"the input needs at least 2 frames, got {n0}")
    if m is None:
        if keytimes:
            raise ValueError("keytimes need an output length (--duration or --frames), not --unconstrained")
        return Reduction(1, n0, None, (), backward)
    if m < 2:
        raise ValueError(f"the output needs at least 2 frames, got {m}")
    if n0 - 1 > skip * (m - 1):
        raise ValueError(
            f"output length {m} frames is below n/s: {n0} input frames need at least "
            f"{math.ceil((n0 - 1) / skip) + 1} output frames with skip {skip}"
        )
    pairs = sorted(((float(i), float(o)) for i, o in keytimes), key=lambda io: io[1])
    for i, o in pairs:
        if not (0.0 <= i <= n0 - 1):
            raise ValueError(f"keytime input frame {i:g} is outside the input (0..{n0 - 1})")
        if not (0.0 <= o <= m - 1):
            raise ValueError(f"keytime output frame {o:g} is outside the output (0..{m - 1})")
    # in the working (possibly reversed) input, input frames must increase with output frames
    src = [(n0 - 1 - i if backward else i, o) for i, o in pairs]
    start, end = (0.0, 0.0), (float(n0 - 1), float(m - 1))
    inner = [kt for kt in src if kt != start and kt != end]
    full = [start, *inner, end]
    for (i0, o0), (i1, o1) in itertools.pairwise(full):
        if not (o1 > o0):
            raise ValueError(f"keytimes must have strictly increasing output times (got {o0:g} then {o1:g})")
        if not (i1 > i0):
            direction = "decreasing (backward warp)" if backward else "increasing"
            raise ValueError(f"keytime input times must be strictly {direction} "
                             f"with output time (segment at output {o0:g}..{o1:g})")
    d_in = np.diff([i for i, _ in full])
    d_out = np.diff([o for _, o in full])
    expand = float(np.max(d_out / d_in))
    compress = float(np.max(d_in / d_out))
    u_min = max(1, math.ceil(expand - 1e-9))
    u_max = math.floor(skip / compress + 1e-9)
    if u_min > u_max:
        raise ValueError(
            f"keytimes ask for speeds from 1/{expand:.3g}x to {compress:.3g}x of the input; a warp with "
            f"skip {skip} covers at most a {skip}x range of speeds"
        )
    # an expansion gets headroom to slow down further than the average (HDP07 §4.3 used 4x for V5)
    u = 1 if expand <= 1.0 else min(u_max, max(u_min, math.ceil(2.0 * expand)))
    keys = [(round(i * u), round(o)) for i, o in full]
    for (i0, o0), (i1, o1) in itertools.pairwise(keys):
        if not (o0 < o1 and i0 < i1 and i1 - i0 >= o1 - o0 and i1 - i0 <= skip * (o1 - o0)):
            raise ValueError(
                f"keytimes {full[1:-1]} round to output frames {[o for _, o in keys[1:-1]]}: segment "
                f"{o0}..{o1} would need {i1 - i0} working input frames in {o1 - o0} steps (skip {skip})"
            )
    return Reduction(u, u * (n0 - 1) + 1, m, tuple(keys), backward)


# ----------------------------------------------------------------------------------------------------------
