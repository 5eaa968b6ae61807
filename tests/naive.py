"""Slow, obviously correct reference implementations the fast kernels are tested against.

Each function here is the plain-Python or plain-numpy statement of what a compiled or vectorised
kernel of the package computes; the tests compare the two on small inputs. Import by module name
(``from naive import ...``): tests are not a package.
"""

from __future__ import annotations

from collections import defaultdict

import numpy as np
from motionweb.store.web import MatchWeb


class TooManySequences(RuntimeError):
    """The enumeration met more match sequences than its budget."""


def ref_matches(web: MatchWeb, a: int, b: int, max_sequences: int | None = None
                ) -> dict[tuple[int, int], tuple[float, float]]:
    """KG04 §3.3 literally: enumerate every match sequence from the earliest row-a cell of each
    path, walking down paths and recursing into every bridge met before row b; a sequence ends at
    the last cell of its row-b run. Returns (c, d) -> (least average, average of least total).
    Exponential in the bridges crossed: raises TooManySequences past ``max_sequences``."""
    count = [0]
    leaving = defaultdict(list)
    for bi, (p, fi, _, _) in enumerate(web.bridges.tolist()):
        leaving[(p, fi)].append(bi)
    best: dict[tuple[int, int], tuple[float, float, float]] = {}

    def record(seq: list[float], c: int, d: int) -> None:
        count[0] += 1
        if max_sequences is not None and count[0] > max_sequences:
            raise TooManySequences(f"more than {max_sequences} match sequences")
        avg, tot = float(np.mean(seq)), float(np.sum(seq))
        old = best.get((c, d), (np.inf, np.inf, np.inf))
        best[(c, d)] = (min(old[0], avg), *(min((old[1], old[2]), (tot, avg))))

    def run_path(p: int, k: int, seq: list[float], c: int) -> None:
        cells, vals = web.path(p)
        for q in range(k, len(cells)):
            seq = [*seq, float(vals[q])]
            if cells[q][0] == b:
                if q + 1 == len(cells) or cells[q + 1][0] != b:
                    record(seq, c, int(cells[q][1]))
                    return
                continue
            for bi in leaving[(p, q)]:
                run_bridge(bi, seq, c)

    def run_bridge(bi: int, seq: list[float], c: int) -> None:
        cells, vals = web.bridge(bi)
        for u in range(1, len(cells) - 1):
            seq = [*seq, float(vals[u])]
            if cells[u][0] == b and cells[u + 1][0] != b:
                record(seq, c, int(cells[u][1]))
                return
        run_path(int(web.bridges[bi][2]), int(web.bridges[bi][3]), seq, c)

    for p in range(web.n_paths):
        cells, _ = web.path(p)
        hit = np.nonzero(cells[:, 0] == a)[0]
        if len(hit):
            run_path(p, int(hit[0]), [], int(cells[hit[0], 1]))
    return {k: (v[0], v[2]) for k, v in best.items()}
