"""Slow, obviously correct reference implementations the fast kernels are tested against.

Each function here is the plain-Python or plain-numpy statement of what a compiled or vectorised
kernel of the package computes; the tests compare the two on small inputs. Import by module name
(``from naive import ...``): tests are not a package.
"""

from __future__ import annotations

import itertools
from collections import defaultdict

import numpy as np
from motionweb.store.web import MatchWeb
from motionweb.tasks.distance import rigid_align_2d
from motionweb.tasks.guided_warp import Track
from motionweb.tasks.retime.objective import BakedObjective, sector
from motionweb.tasks.search import WalkGraph, _check_web, _narrow, _ranges, _with_switches


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
        if is_switch(web, bi):  # two paths share a cell: go on along the joined path past it
            q, j = int(web.bridges[bi][2]), int(web.bridges[bi][3])
            for bj in leaving[(q, j)]:
                if not is_switch(web, bj):
                    run_bridge(bj, seq, c)
            run_path(q, j + 1, seq, c)
            return
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


def is_switch(web: MatchWeb, bi: int) -> bool:
    """A bridge of fewer than two cells, or whose junction cells coincide: two paths share a cell
    and the walk switches path there (no step of its own)."""
    p, i, q, j = web.bridges[bi].tolist()
    return len(web.bridge(bi)[0]) < 2 or tuple(web.path(p)[0][i]) == tuple(web.path(q)[0][j])


def ref_walk_steps(web: MatchWeb) -> list[tuple[tuple[int, int], tuple[int, int], float]]:
    """Every step a walk can take in ``web`` (KG04 §3.3), as (cell, next cell, next cell's value):
    along each path, from a path cell through a bridge's interior onto the path cell it joins, and
    through a switch (:func:`is_switch`) from the shared cell to the first step of what follows it
    on the joined path (its next cell, and the first cell of each proper bridge leaving it)."""
    out = []
    for p in range(web.n_paths):
        cells, vals = web.path(p)
        out += [(tuple(cells[i]), tuple(cells[i + 1]), float(vals[i + 1])) for i in range(len(cells) - 1)]
    first_steps = defaultdict(list)  # (path, index) -> the first steps of its proper bridges
    for bi, (p, i, q, j) in enumerate(web.bridges.tolist()):
        if is_switch(web, bi):
            continue
        cells, vals = web.bridge(bi)
        nxt = (tuple(cells[1]), float(vals[1])) if len(cells) > 2 else (tuple(web.path(q)[0][j]), float(web.path(q)[1][j]))
        first_steps[(p, i)].append(nxt)
    for bi, (p, i, q, j) in enumerate(web.bridges.tolist()):
        if is_switch(web, bi):
            here = tuple(web.path(p)[0][i])
            qc, qv = web.path(q)
            if j + 1 < len(qc):
                out.append((here, tuple(qc[j + 1]), float(qv[j + 1])))
            out += [(here, c, v) for c, v in first_steps[(q, j)]]
            continue
        cells, vals = web.bridge(bi)
        vals = [*vals[:-1], web.path(q)[1][j]]  # the joined cell keeps its path value
        cells = [tuple(web.path(p)[0][i]), *map(tuple, cells[1:-1]), tuple(web.path(q)[0][j])]
        out += [(cells[k], cells[k + 1], float(vals[k + 1])) for k in range(len(cells) - 1)]
    return [((int(a), int(b)), (int(c), int(d)), v) for (a, b), (c, d), v in out]


def ref_row_starts(web: MatchWeb, a: int) -> list[tuple[int, int]]:
    """The cells where the walks of rows a.. start (KG04 §3.3): the earliest row-a cell of each
    path that has one, in path order."""
    out = []
    for p in range(web.n_paths):
        cells, _ = web.path(p)
        hit = np.nonzero(cells[:, 0] == a)[0]
        if len(hit):
            out.append((int(cells[hit[0], 0]), int(cells[hit[0], 1])))
    return out


def slow_grid(fa: np.ndarray, fb: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Reference: explicit best 2-D alignment of every pair of clouds, one pair at a time."""
    out = np.empty((len(fa), len(fb)))
    for i in range(len(fa)):
        for j in range(len(fb)):
            out[i, j] = rigid_align_2d(fa[i], fb[j], w)[2]
    return out


def slow_scores(track: Track, ref: Track, skip: int, k: int, spec) -> np.ndarray:
    """f(i, j, k) one triple at a time: explicit rotation matrices and a full sort (eq. 2)."""

    def rot_y(a: float) -> np.ndarray:  # right-handed rotation about +y by angle a
        return np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])

    def feat(tr: Track, i: int, j: int, kk: int) -> np.ndarray:
        inv = rot_y(tr.angle[j]).T
        pose = (tr.positions[j] - tr.origin[j]) @ inv.T
        vel = 0.5 * (tr.positions[kk] - tr.positions[i]) @ inv.T
        acc = (tr.positions[kk] - 2 * tr.positions[j] + tr.positions[i]) @ inv.T
        parts = [w / s * p.ravel() for w, s, p in zip(spec.weights, spec.scales, (pose, vel, acc), strict=True)]
        return np.concatenate(parts)

    refs = [feat(ref, t - 1, t, t + 1) for t in range(1, len(ref) - 1)]
    n = len(track)
    out = np.full((n, skip, skip), np.inf)
    for j in range(n):
        for a in range(1, skip + 1):
            for b in range(1, skip + 1):
                if j - a >= 0 and j + b < n:
                    q = feat(track, j - a, j, j + b)
                    d = sorted(float(np.linalg.norm(q - z)) for z in refs)
                    out[j, a - 1, b - 1] = sum(d[:k]) / k
    return out

def brute_force(table: np.ndarray, m: int | None, keys=()) -> tuple[float, tuple[int, ...] | None]:
    """Cheapest subsequence by enumeration (m None: any length)."""
    n, s, _ = table.shape
    best, arg = np.inf, None
    sizes = range(n - 1) if m is None else [m - 2]
    for size in sizes:
        for mid in itertools.combinations(range(1, n - 1), size):
            y = (0, *mid, n - 1)
            if any(b - a > s for a, b in itertools.pairwise(y)):
                continue
            if any(o >= len(y) or y[o] != f for f, o in keys):
                continue
            c = sum(table[y[p], y[p] - y[p - 1] - 1, y[p + 1] - y[p] - 1] for p in range(1, len(y) - 1))
            if c < best:
                best, arg = c, y
    return best, arg


def ref_minima(g: np.ndarray) -> np.ndarray:
    fa, fb = g.shape
    out = np.zeros(g.shape, np.uint8)
    for i in range(fa):
        for j in range(fb):
            v = g[i, j]
            if not np.isfinite(v):
                continue
            left = g[i, j - 1] if j > 0 else np.inf
            right = g[i, j + 1] if j < fb - 1 else np.inf
            below = g[i - 1, j] if i > 0 else np.inf
            above = g[i + 1, j] if i < fa - 1 else np.inf
            out[i, j] = (1 if v < left and v <= right else 0) | (2 if v < below and v <= above else 0)
    return out

def ref_valid(g: np.ndarray, minima: np.ndarray, a: float) -> np.ndarray:
    out = np.zeros(g.shape, bool)
    for i, j in zip(*np.nonzero(minima), strict=True):
        out[i, j] = True
        lim = (1 + a) * g[i, j]
        dirs = ([(0, 1), (0, -1)] if minima[i, j] & 1 else []) + ([(1, 0), (-1, 0)] if minima[i, j] & 2 else [])
        for di, dj in dirs:
            ii, jj = i + di, j + dj
            while 0 <= ii < g.shape[0] and 0 <= jj < g.shape[1] and g[ii, jj] < lim:
                out[ii, jj] = True
                ii, jj = ii + di, jj + dj
    return out

def ref_chains(g: np.ndarray, minima: np.ndarray, k: int, min_extent: int) -> list[list[tuple[int, int]]]:
    used = np.zeros(g.shape, bool)
    chains = []
    for i, j in itertools.product(range(g.shape[0]), range(g.shape[1])):
        if not minima[i, j] or used[i, j]:
            continue
        chain, r = [(i, j)], 0
        used[i, j] = True
        while True:
            ii, jj = chain[-1]
            cands = [(ii + 1, jj + 1, 0), (ii + 1, jj, r + 1 if r > 0 else 1), (ii, jj + 1, r - 1 if r < 0 else -1)]
            best = None
            for ci, cj, nr in cands:
                if abs(nr) > k - 1 or ci >= g.shape[0] or cj >= g.shape[1] or not minima[ci, cj] or used[ci, cj]:
                    continue
                if best is None or g[ci, cj] < g[best[0], best[1]]:
                    best = (ci, cj, nr)
            if best is None:
                break
            chain.append(best[:2])
            used[best[0], best[1]] = True
            r = best[2]
        if max(chain[-1][0] - i, chain[-1][1] - j) >= min_extent:
            chains.append(chain)
        else:
            for c in chain:
                used[c] = False
    return chains

def slope_ok(cells: np.ndarray, k: int) -> bool:
    """Monotone unit steps with at most k − 1 consecutive steps along one axis."""
    d = np.diff(np.asarray(cells), axis=0)
    if not np.all((d >= 0) & (d <= 1)) or np.any(d.sum(axis=1) == 0):
        return False
    run, prev = 0, None
    for step in map(tuple, d):
        if step == (1, 1):
            run, prev = 0, None
            continue
        run = run + 1 if step == prev else 1
        prev = step
        if run > k - 1:
            return False
    return True

def all_paths(start: tuple[int, int], n_steps_max: int, ok) -> list[list[tuple[int, int]]]:
    """Every monotone path from ``start`` of at most ``n_steps_max`` Manhattan length through ok cells."""
    out = []

    def rec(path: list[tuple[int, int]], manhattan: int) -> None:
        out.append(list(path))
        i, j = path[-1]
        for di, dj in ((1, 1), (1, 0), (0, 1)):
            c = (i + di, j + dj)
            if manhattan + di + dj <= n_steps_max and ok(c, path):
                path.append(c)
                rec(path, manhattan + di + dj)
                path.pop()

    rec([start], 0)
    return out

def ref_bridges(g: np.ndarray, valid: np.ndarray, cells: np.ndarray, offs: np.ndarray,
                L: int) -> dict[tuple[int, int], float]:
    """Slow reference of find_bridges: over every chain cell start, the least-total path to each
    C' cell (inside the valid region, slope rule k = 3, Manhattan < L, not through chain cells),
    the least average kept per (C, C'). Returns {(C, C'): average}."""
    owner = -np.ones(g.shape, int)
    for c, (a, b) in enumerate(itertools.pairwise(offs)):
        owner[cells[a:b, 0], cells[a:b, 1]] = c
    want: dict[tuple[int, int], float] = {}
    for c, (a, b) in enumerate(itertools.pairwise(offs)):
        for start in map(tuple, cells[a:b].tolist()):
            def ok(cell, path, c=c):
                if cell[0] >= g.shape[0] or cell[1] >= g.shape[1] or not valid[cell] or owner[cell] == c:
                    return False
                return all(owner[x] < 0 for x in path[1:])  # chain cells end a path

            best_total: dict[tuple[int, int], tuple[float, float]] = {}
            for p in all_paths(start, L - 1, ok):
                end = p[-1]
                if owner[end] < 0 or owner[end] == c or not slope_ok(np.array(p), 3):
                    continue
                tot = float(sum(g[x] for x in p))
                if end not in best_total or tot < best_total[end][0]:
                    best_total[end] = (tot, tot / len(p))
            for end, (_, avg) in best_total.items():
                key = (c, int(owner[end]))
                want[key] = min(want.get(key, np.inf), avg)
    return want


def ref_band_dp(lo, hi, off, vals, init, flags, mrun) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``tasks.matchweb.band.band_dp``'s outputs (cost, length, predecessor state per cell and
    state), one transition at a time in plain Python: every cell's states start unreached, a
    source sets state 0 (s = mrun); then the diagonal, up and right predecessors are tried in that
    order, each over its states in ascending order, and a candidate replaces a state's value only
    when strictly smaller (the first of equal costs is kept). Blocked cells (inf or NaN value, flag
    1) stay unreached; a terminal cell (flag 2) is never a predecessor."""
    n, ns, c0 = int(off[-1]), 2 * mrun + 1, mrun
    cost = np.full((n, ns), np.inf)
    length = np.zeros((n, ns), np.int32)
    ptr = np.full((n, ns), -2, np.int8)

    def cell(t: int, j: int) -> int | None:
        if t < 0 or not lo[t] <= j <= hi[t]:
            return None
        return int(off[t] + j - lo[t])

    for t in range(len(lo)):
        for j in range(int(lo[t]), int(hi[t]) + 1):
            k = cell(t, j)
            v = float(vals[k])
            if not v < np.inf or flags[k] == 1:
                continue
            if init[k] < np.inf:
                cost[k, c0], length[k, c0], ptr[k, c0] = init[k], 1, -1
            moves = [(cell(t - 1, j - 1), lambda r: 0)]
            if mrun > 0:
                moves.append((cell(t - 1, j), lambda r: r + 1 if r > 0 else 1))
                moves.append((cell(t, j - 1), lambda r: r - 1 if r < 0 else -1))
            for pred, run in moves:
                if pred is None or flags[pred] == 2:
                    continue
                for s in range(ns):
                    nr = run(s - c0)
                    if abs(nr) > mrun:
                        continue
                    c = cost[pred, s] + v
                    if c < cost[k, c0 + nr]:
                        cost[k, c0 + nr], length[k, c0 + nr], ptr[k, c0 + nr] = c, length[pred, s] + 1, s
    return cost, length, ptr


def ref_alignment_cost(g: np.ndarray, slope_k: int) -> float:
    """Least total cost of a monotone path (0, 0) → (n − 1, m − 1) over finite cells with at most
    ``slope_k − 1`` consecutive steps along one axis (inf when there is none). Pure Python DP over
    (row, column, run): run r > 0 counts the up steps just taken, r < 0 the right steps, 0 after a
    diagonal step or at the start."""
    n, m = g.shape
    mrun = slope_k - 1
    best: dict[tuple[int, int, int], float] = {(0, 0, 0): float(g[0, 0])}
    for i in range(n):
        for j in range(m):
            if not np.isfinite(g[i, j]) or (i, j) == (0, 0):
                continue
            for r in range(-mrun, mrun + 1):
                if r == 0:
                    prev = [best.get((i - 1, j - 1, s), np.inf) for s in range(-mrun, mrun + 1)]
                elif r == 1:
                    prev = [best.get((i - 1, j, s), np.inf) for s in range(-mrun, 1)]
                elif r > 1:
                    prev = [best.get((i - 1, j, r - 1), np.inf)]
                elif r == -1:
                    prev = [best.get((i, j - 1, s), np.inf) for s in range(mrun + 1)]
                else:
                    prev = [best.get((i, j - 1, r + 1), np.inf)]
                c = min(prev) + g[i, j]
                if c < np.inf:
                    best[(i, j, r)] = c
    return min(best.get((n - 1, m - 1, r), np.inf) for r in range(-mrun, mrun + 1))


def _frame_terms(obj: BakedObjective, fr: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-sample value (S,), gradient (S, 2) and closest feasible point (S, 2) of one frame's terms."""
    s = sector(obj, fr, x)
    k = obj.coef[fr, s]  # (S, 6)
    x0, x1 = x[:, 0], x[:, 1]
    val = k[:, 0] * x0 * x0 + k[:, 1] * x0 * x1 + k[:, 2] * x1 * x1 + k[:, 3] * x0 + k[:, 4] * x1 + k[:, 5]
    grad = np.stack([2 * k[:, 0] * x0 + k[:, 1] * x1 + k[:, 3], k[:, 1] * x0 + 2 * k[:, 2] * x1 + k[:, 4]], axis=1)
    # distance to the polygon
    v = obj.verts[fr]  # (S, K, 2)
    e = np.roll(v, -1, axis=1) - v
    rel = x[:, None, :] - v
    cross = e[..., 0] * rel[..., 1] - e[..., 1] * rel[..., 0]
    inside = obj.solid[fr] & np.all(cross >= 0, axis=1)
    ee = np.maximum((e * e).sum(axis=2), 1e-300)
    t = np.clip((rel * e).sum(axis=2) / ee, 0.0, 1.0)
    proj = v + t[..., None] * e
    d2 = ((x[:, None, :] - proj) ** 2).sum(axis=2)
    j = np.argmin(d2, axis=1)
    cp = proj[np.arange(len(fr)), j]
    cp[inside] = x[inside]
    diff = x - cp
    val = val + obj.alpha[fr] * (diff * diff).sum(axis=1)
    grad = grad + 2 * obj.alpha[fr][:, None] * diff
    return val, grad, cp


def evaluate_numpy(obj: BakedObjective, u: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """MPS06 Eqn. 14's density in plain numpy: the reference of ``motionweb.tasks.retime.objective.evaluate``
    (value (S,), d/dx (S, 2), d/du (S,) at source frames ``u`` (S,) and x = (p̈, ṗ²) (S, 2))."""
    f = obj.n_frames
    u = np.clip(u, 0.0, f - 1.0)
    i0 = np.minimum(np.floor(u).astype(np.int64), max(f - 2, 0))
    i1 = np.minimum(i0 + 1, f - 1)
    w = u - i0
    v0, g0, _ = _frame_terms(obj, i0, x)
    v1, g1, _ = _frame_terms(obj, i1, x)
    val = (1 - w) * v0 + w * v1
    gx = (1 - w)[:, None] * g0 + w[:, None] * g1
    return val, gx, v1 - v0


def ref_blend_frame(local: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Blend of (N, J, 4) local rotations of one sample, joint by joint with
    ``store.kinematics.quat_average`` (hemisphere of the heaviest example)."""
    from motionweb.store.kinematics import quat_average

    return np.stack([quat_average(local[:, j], weights) for j in range(local.shape[1])])


def ref_forward_kinematics(motion) -> tuple[np.ndarray, np.ndarray]:
    """Global positions (F, J, 3) and rotations (F, J, 4) by the NumPy quaternion formulas, one
    joint at a time (``store.kinematics.forward_kinematics`` compiles the same operations)."""
    from motionweb.store.kinematics import quat_mul, quat_rotate

    trans = motion.local_translations()
    grot = np.empty_like(motion.rotations)
    gpos = np.empty_like(trans)
    grot[:, 0], gpos[:, 0] = motion.rotations[:, 0], trans[:, 0]
    for j in range(1, motion.skeleton.n_joints):
        p = motion.skeleton.parents[j]
        grot[:, j] = quat_mul(grot[:, p], motion.rotations[:, j])
        gpos[:, j] = gpos[:, p] + quat_rotate(grot[:, p], trans[:, j])
    return gpos, grot


def ref_leg_ik(motion, chain: tuple[int, int, int], frame: int, target: np.ndarray) -> float:
    """Smallest ankle-to-target distance reachable by turning the hip and knee of one frame
    (Nelder-Mead over rotation vectors of both joints): the distance leg IK must reach."""
    from dataclasses import replace

    from motionweb.store.kinematics import forward_kinematics, quat_exp, quat_mul
    from scipy.optimize import minimize

    hip, knee, ankle = chain
    m = replace(motion, root_positions=motion.root_positions[frame:frame + 1],
                rotations=motion.rotations[frame:frame + 1].copy())

    def miss(x: np.ndarray) -> float:
        rot = m.rotations.copy()
        rot[0, hip] = quat_mul(m.rotations[0, hip], quat_exp(x[:3]))
        rot[0, knee] = quat_mul(m.rotations[0, knee], quat_exp(x[3:]))
        g, _ = forward_kinematics(replace(m, rotations=rot))
        return float(np.linalg.norm(g[0, ankle] - target))

    best = minimize(miss, np.zeros(6), method="Nelder-Mead", options={"xatol": 1e-10, "fatol": 1e-12, "maxiter": 20000})
    return float(best.fun)


def numpy_rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(F, 4) the shortest rotations taking directions a (F, 3) onto b (F, 3), in numpy."""
    from motionweb.store.kinematics import quat_normalize

    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    c = np.cross(a, b)
    d = np.sum(a * b, axis=-1)
    q = np.concatenate([(1.0 + d)[:, None], c], axis=-1)
    opposite = d < -1.0 + 1e-12
    if opposite.any():  # any axis perpendicular to a
        perp = np.cross(a[opposite], np.array([1.0, 0.0, 0.0]))
        small = np.linalg.norm(perp, axis=-1) < 1e-6
        perp[small] = np.cross(a[opposite][small], np.array([0.0, 0.0, 1.0]))
        q[opposite] = np.concatenate([np.zeros((opposite.sum(), 1)), perp], axis=-1)
    return quat_normalize(q)


def numpy_leg_ik(gpos, grot, parents, chain, target, fallback_axis):
    """``motionweb.tasks.blend.leg_ik`` step by step in numpy over all frames at once (the
    reference of the compiled kernel): bend the knee about its axis to the law-of-cosines angle,
    swing the leg about the hip onto the target, keep the foot's global rotation."""
    from motionweb.store.kinematics import quat_from_axis_angle, quat_inv, quat_mul, quat_rotate

    hip, knee, ankle = chain
    h, k, a = gpos[:, hip], gpos[:, knee], gpos[:, ankle]
    l1 = np.linalg.norm(k - h, axis=-1)
    l2 = np.linalg.norm(a - k, axis=-1)
    d_t = np.linalg.norm(target - h, axis=-1)
    dc = np.clip(d_t, np.abs(l1 - l2) + 1e-9, (l1 + l2) * (1.0 - 1e-9))
    d0 = np.linalg.norm(a - h, axis=-1)
    beta0 = np.arccos(np.clip((l1 ** 2 + l2 ** 2 - d0 ** 2) / (2 * l1 * l2), -1.0, 1.0))
    beta = np.arccos(np.clip((l1 ** 2 + l2 ** 2 - dc ** 2) / (2 * l1 * l2), -1.0, 1.0))
    axis = np.cross(k - h, a - k)
    norm = np.linalg.norm(axis, axis=-1, keepdims=True)
    axis = np.where(norm > 1e-9 * np.maximum(l1 * l2, 1e-12)[:, None], axis / np.maximum(norm, 1e-300), fallback_axis)
    bend = quat_from_axis_angle(axis, beta0 - beta)
    a1 = k + quat_rotate(bend, a - k)
    swing = numpy_rotation_between(a1 - h, target - h)
    g_hip = quat_mul(swing, grot[:, hip])
    g_knee = quat_mul(swing, quat_mul(bend, grot[:, knee]))
    p = parents[hip]
    g_parent = grot[:, p] if p >= 0 else np.tile([1.0, 0.0, 0.0, 0.0], (len(h), 1))
    local_hip = quat_mul(quat_inv(g_parent), g_hip)
    local_knee = quat_mul(quat_inv(g_hip), g_knee)
    local_ankle = quat_mul(quat_inv(g_knee), grot[:, ankle])
    return local_hip, local_knee, local_ankle, np.abs(d_t - dc)


def numpy_hold_plants(motion, legs, plants, cfg):
    """``motionweb.tasks.blend.hold_plants`` the obvious way: one full FK of the motion, then
    :func:`numpy_leg_ik` and :func:`numpy_ease_offsets` per leg. Returns (motion, worst miss)."""
    from motionweb.store.kinematics import forward_kinematics
    from motionweb.tasks.blend import hold_plants

    return hold_plants(motion, legs, plants, cfg, forward_kinematics(motion), ik=numpy_leg_ik,
                       ease=numpy_ease_offsets)


def numpy_ease_offsets(n: int, plants: np.ndarray, ankles: np.ndarray, ramp: int) -> tuple[np.ndarray, np.ndarray]:
    """``motionweb.tasks.blend.ease_offsets`` in numpy, run by run: each planted run held at its
    mean ankle position, smoothstep ramps of ``ramp`` frames either side, overlaps averaged."""
    from motionweb.tasks.blend import runs

    off = np.zeros((n, 3))
    wsum = np.zeros(n)
    for a, b in runs(plants):
        hold = ankles[a:b + 1].mean(axis=0)
        off[a:b + 1] += hold - ankles[a:b + 1]
        wsum[a:b + 1] += 1.0
        for side_frames, edge in ((np.arange(max(0, a - ramp), a), a), (np.arange(b + 1, min(n, b + 1 + ramp)), b)):
            if len(side_frames):
                s = 1.0 - np.abs(side_frames - edge) / (ramp + 1.0)
                s = s * s * (3.0 - 2.0 * s)
                off[side_frames] += s[:, None] * (hold - ankles[edge])
                wsum[side_frames] += 1.0
    mask = wsum > 0
    off[mask] /= np.maximum(wsum[mask], 1.0)[:, None]
    return off, mask


def ref_dynamics_terms(body, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """MPS06 §3.1 per-body path-dynamics terms (a, b, c) from five full joint-torque regressors per
    frame, stored whole and contracted with each body's parameters afterwards (the plain statement
    of ``tasks.retime.dynamics.dynamics_terms``): a (F, nv, B), b (F, nv, B), c (F, nv, B, 3)."""
    import pinocchio as pin

    m = body.model.copy()
    d = m.createData()
    f, nv, nb = q.shape[0], m.nv, body.n_bodies
    zero = np.zeros(nv)
    reg = pin.computeJointTorqueRegressor
    ya = np.empty((f, nv, nb * 10))
    yb = np.empty((f, nv, nb * 10))
    yc = np.empty((3, f, nv, nb * 10))
    m.gravity = pin.Motion.Zero()
    for i in range(f):
        ya[i] = reg(m, d, q[i], zero, dq[i])
        yb[i] = reg(m, d, q[i], dq[i], ddq[i])
    for k in range(3):
        e = np.zeros(6)
        e[k] = 1.0
        m.gravity = pin.Motion(e)
        for i in range(f):
            yc[k, i] = reg(m, d, q[i], zero, zero)
    pi = body.params
    a = np.einsum("fvbk,bk->fvb", ya.reshape(f, nv, nb, 10), pi)
    b = np.einsum("fvbk,bk->fvb", yb.reshape(f, nv, nb, 10), pi)
    c = np.einsum("efvbk,bk->fvbe", yc.reshape(3, f, nv, nb, 10), pi)
    return a, b, c


def ref_remove_redundant(matches, overlap: float) -> list:
    """KG04 §3.3 redundancy removal literally: by increasing (cost, clip, start, end), keep a match
    unless it overlaps a kept one (``Segment.overlap``) by more than ``overlap``."""
    kept = []
    for m in sorted(matches, key=lambda x: (x.cost, x.clip, x.start, x.end)):
        if all(m.segment.overlap(k.segment) <= overlap for k in kept):
            kept.append(m)
    return kept


def ref_place(nodes: list, matches: list, new_below: float, merge_above: float) -> list:
    """KG04 §3.3 dedup of matches (``Segment``) against graph nodes (``Segment``, ``nodes[0]`` the
    query), one match at a time: the largest ``Segment.overlap`` with a node (the first on ties);
    below ``new_below`` a new node, above ``merge_above`` the node's interval averaged with the
    match's (the query node kept), otherwise discarded. Updates ``nodes``; returns per match its
    node or None."""
    from motionweb.tasks.matchgraph import Segment

    out = []
    for m in matches:
        ov = [m.overlap(n) for n in nodes]
        k = int(np.argmax(ov))
        if nodes[k].clip != m.clip or ov[k] < new_below:
            nodes.append(m)
            out.append(len(nodes) - 1)
        elif ov[k] > merge_above:
            if k != 0:
                nodes[k] = Segment(m.clip, round((nodes[k].start + m.start) / 2), round((nodes[k].end + m.end) / 2))
            out.append(k)
        else:
            out.append(None)
    return out


def in_convex(v: np.ndarray, pt: np.ndarray, tol: float = 1e-9) -> bool:
    """Whether ``pt`` lies in the convex counter-clockwise polygon ``v`` (K, 2), a segment or a point."""
    if len(v) == 1:
        return bool(np.abs(v[0] - pt).max() <= tol)
    if len(v) == 2 or abs((v[1, 0] - v[0, 0]) * (v[2, 1] - v[0, 1]) - (v[1, 1] - v[0, 1]) * (v[2, 0] - v[0, 0])) < 1e-15:
        a, b = v[0], v[-1]
        t = np.clip(np.dot(pt - a, b - a) / max(np.dot(b - a, b - a), 1e-300), 0, 1)
        return bool(np.linalg.norm(a + t * (b - a) - pt) <= tol)
    nxt = np.roll(v, -1, axis=0)
    cross = (nxt[:, 0] - v[:, 0]) * (pt[1] - v[:, 1]) - (nxt[:, 1] - v[:, 1]) * (pt[0] - v[:, 0])
    return bool((cross >= -tol).all())


def grid_fastest(vertices: list[np.ndarray], fps: float, grid: np.ndarray) -> float:
    """The shortest duration over every profile of ṗ² values on ``grid`` at each frame (exhaustive):
    the p̈ = (x_{i+1} − x_i) fps / 2 of each interval must lie, with every ṗ² of its first half, in
    frame i's polygon and, with every ṗ² of its second half, in frame i + 1's (ṗ² runs linearly, so
    the ends of each half); the last frame's ṗ² within its polygon's range of ṗ². O(F · G²) pairs,
    combined exhaustively (G^F profiles)."""
    f, d = len(vertices), 1.0 / fps

    def fits(i: int, a: float, b: float) -> bool:
        acc, mid = (b - a) / (2 * d), (a + b) / 2
        return all(in_convex(vertices[j], np.array([acc, x])) for j, x in ((i, a), (i, mid), (i + 1, mid), (i + 1, b)))

    ok = [np.array([[fits(i, a, b) for b in grid] for a in grid]) for i in range(f - 1)]
    last = (grid >= vertices[-1][:, 1].min()) & (grid <= vertices[-1][:, 1].max())
    best = np.inf
    for prof in itertools.product(range(len(grid)), repeat=f):
        if not last[prof[-1]] or not all(ok[i][prof[i], prof[i + 1]] for i in range(f - 1)):
            continue
        s = np.sqrt(grid[list(prof)])
        best = min(best, float((2 * d / (s[1:] + s[:-1])).sum()))
    return best


def box_polygon(amax: float, x0: float, x1: float) -> np.ndarray:
    """The (p̈, ṗ²) polygon |p̈| ≤ amax, x0 ≤ ṗ² ≤ x1, counter-clockwise (4, 2)."""
    return np.array([[-amax, x0], [amax, x0], [amax, x1], [-amax, x1]])


def polygons_of(vertices: list[np.ndarray], box: tuple[float, float] | None = None):
    """``FeasiblePolygons`` of given per-frame vertices clipped to ``box`` (max |p̈|, max ṗ²; None:
    ``PolygonParams``' pdd_max and speed_max²), no contact forces, the original timing inside."""
    from motionweb.tasks.params.retime import PolygonParams
    from motionweb.tasks.retime.polygons import FeasiblePolygons

    if box is None:
        box = (PolygonParams().pdd_max, PolygonParams().speed_max ** 2)
    f = len(vertices)
    return FeasiblePolygons(vertices=vertices, lambdas=[np.zeros((len(v), 1)) for v in vertices],
                            center=np.tile([0.0, 1.0], (f, 1)), center_lambda=np.zeros((f, 1)), residual=np.zeros(f),
                            tolerance=np.zeros((f, 6)), infeasible=np.zeros(f, bool),
                            original_inside=np.ones(f, bool), n_lps=0, seconds=0.0, cpu_seconds=0.0, box=box)


def greedy_free(vertices: list[np.ndarray], fps: float, duration: float, batch: int = 1,
                batch_gain: float = 0.8, weight: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``reachable.free_frames`` from scratch, one frame per unit: each step tries freeing (polygon →
    box) every frame not yet freed, rebuilding all polygons and running ``fastest_timing`` anew,
    ranks them by the output seconds saved per output frame left outside (its own 1/√x, half of
    each unfreed neighbour's, each frame's times its ``weight``, default 1) and frees the best, then up to ``batch`` − 1 more in rank order
    while they gain at least ``batch_gain`` of the best and their summed savings fit in what is
    missing, until the fastest profile lasts ≤
    ``duration``; then restores freed frames in order while it still fits. (freed (F,), fastest
    profile (F,))."""
    from motionweb.tasks.retime.reachable import fastest_timing

    f, d = len(vertices), 1.0 / fps
    w = np.ones(f) if weight is None else weight

    def fastest(mask: np.ndarray) -> np.ndarray:
        return fastest_timing(polygons_of([np.zeros((0, 2)) if mask[i] else v for i, v in enumerate(vertices)]), fps).x

    def length(x: np.ndarray) -> float:
        s = np.sqrt(x)
        return float((2 * d / (s[1:] + s[:-1])).sum())

    freed = np.zeros(f, bool)
    x = fastest(freed)
    while length(x) > duration:
        ranked = []
        for i in range(f):
            if freed[i]:
                continue
            trial = freed.copy()
            trial[i] = True
            x2 = fastest(trial)
            spent = w[i] / np.sqrt(x2[i]) + sum(0.5 * w[j] / np.sqrt(x2[j]) for j in (i - 1, i + 1)
                                                if 0 <= j < f and not freed[j])
            saving = length(x) - length(x2)
            ranked.append((-saving / spent, i, saving))
        ranked.sort()  # best gain first, ties by frame
        assert ranked and ranked[0][0] < 0, "nothing helps"
        taken = 0.0
        for r, (neg_gain, i, saving) in enumerate(ranked[:batch]):
            if neg_gain >= 0 or (r and (neg_gain > batch_gain * ranked[0][0] or taken + saving > length(x) - duration)):
                break
            taken += saving
            freed[i] = True
        x = fastest(freed)
    for i in np.flatnonzero(freed):
        trial = freed.copy()
        trial[i] = False
        x2 = fastest(trial)
        if length(x2) <= duration:
            freed, x = trial, x2
    return freed, x


def ref_upsample_band(cells: np.ndarray, s: float, h: float, fa: int, fb: int) -> dict[int, tuple[int, int]]:
    """``tasks.matchweb.refine.upsample_band`` cell by cell: each coarse cell (i, j) covers fine rows
    ⌊(i − h)s⌋..⌈(i + h)s⌉ and columns ⌊(j − h)s⌋..⌈(j + h)s⌉ clipped to the fa × fb grid; each fine
    row spans from the least to the greatest column any cell covers on it. {row: (lo, hi)}."""
    import math

    out: dict[int, tuple[int, int]] = {}
    for i, j in np.asarray(cells).tolist():
        a, b = max(0, math.floor((i - h) * s)), min(fa - 1, math.ceil((i + h) * s))
        c1, c2 = max(0, math.floor((j - h) * s)), min(fb - 1, math.ceil((j + h) * s))
        if a > b or c1 > c2:
            continue
        for r in range(a, b + 1):
            lo, hi = out.get(r, (c1, c2))
            out[r] = (min(lo, c1), max(hi, c2))
    return out


def ref_path_cells_near(row0: int, lo: np.ndarray, hi: np.ndarray, off: np.ndarray, path: np.ndarray, ci: float,
                        cj: float, radius: int) -> list[int]:
    """``tasks.matchweb.refine._path_cells_near`` as a scan of the whole path: the band's flat
    indices of the path cells within Chebyshev ``radius`` of (ci, cj), in path order."""
    out = []
    for i, j in np.asarray(path).tolist():
        t = i - row0
        if abs(i - ci) <= radius and abs(j - cj) <= radius and 0 <= t < len(lo) and lo[t] <= j <= hi[t]:
            out.append(int(off[t] + j - lo[t]))
    return out


def ref_position(path: np.ndarray, i: int, j: int) -> int:
    """Index of the first cell (i, j) of ``path``, or −1, by a scan."""
    for q, (a, b) in enumerate(np.asarray(path).tolist()):
        if (a, b) == (i, j):
            return q
    return -1


def ref_timing_distances(polys, fps: float, p: np.ndarray, pd: np.ndarray, pdd: np.ndarray):
    """The loop ``tasks.retime.polygons.timing_distances`` compiles: each output frame's (p̈, ṗ²)
    against its nearest source frame's polygon through ``closest_point`` (the fan centre for an
    empty polygon). Returns (frames, distances, inside)."""
    from motionweb.tasks.retime.polygons import closest_point

    n = len(polys.vertices)
    frames = np.clip(np.rint(np.asarray(p) * fps).astype(int), 0, n - 1)
    dist = np.empty(len(frames))
    for k, i in enumerate(frames):
        x = np.array([pdd[k], pd[k] ** 2])
        cp = closest_point(polys.vertices[i], x) if len(polys.vertices[i]) else polys.center[i]
        dx, dy = x - cp
        dist[k] = np.sqrt(dx * dx + dy * dy)
    scale = 1 + np.maximum(np.abs(pdd), np.asarray(pd) ** 2)
    return frames, dist, dist <= 1e-3 * scale


def ref_shortlist(clips: dict, k: int, k_windows: int, min_hits: int, headings: int,
                  stride: int = 1, hub_ratio: float = 0.0) -> list[tuple[str, str]]:
    """``tasks.shortlist.shortlist_pairs`` by brute force: every window's squared distance to every
    window of every other clip with the query turned to each of ``headings`` headings (point by
    point, with explicit centroids and weights); per heading its ``k_windows`` nearest windows
    (ties by window order); over their union, each clip at its nearest window, the ``k`` nearest
    clips (ties by window order). Hubs (issue 25, part 4; ``hub_ratio`` > 0): when the window has
    ``k`` such clips and the ``k``-th is within ``hub_ratio`` × the nearest, also every other clip
    whose nearest window over all its windows and headings is within ``hub_ratio`` × the nearest.
    The pairs of clips with ≥ ``min_hits`` (window, other clip) hits in either direction, every
    self pair included. O(W²·headings·P)."""
    keys = sorted(clips)
    wins = []  # (clip index, centred cloud (P, 3), weights)
    for ci, key in enumerate(keys):
        f, w = clips[key]
        for fr in range(0, len(f), stride):
            c = np.asarray(f[fr], np.float64).copy()
            c[:, 0] -= np.sum(w * c[:, 0])
            c[:, 2] -= np.sum(w * c[:, 2])
            wins.append((ci, c, np.asarray(w, np.float64)))
    hits: dict[tuple[int, int], int] = defaultdict(int)
    for ca, p, w in wins:
        seen: dict[int, tuple[float, int]] = {}  # window -> (least distance over the headings, window)
        every: dict[int, float] = {}  # other clip -> least distance over all its windows and headings
        for h in range(headings):
            a = 2 * np.pi * h / headings
            x = np.cos(a) * p[:, 0] + np.sin(a) * p[:, 2]
            z = -np.sin(a) * p[:, 0] + np.cos(a) * p[:, 2]
            cand = sorted((float(np.sum(w * ((x - q[:, 0]) ** 2 + (p[:, 1] - q[:, 1]) ** 2 + (z - q[:, 2]) ** 2))), di)
                          for di, (cb, q, _) in enumerate(wins) if cb != ca)
            for d, di in cand[:k_windows]:
                seen[di] = min(seen.get(di, (np.inf, di)), (d, di))
            for d, di in cand:
                every[wins[di][0]] = min(every.get(wins[di][0], np.inf), d)
        nearest: dict[int, tuple[float, int]] = {}
        for d, di in seen.values():
            cb = wins[di][0]
            nearest[cb] = min(nearest.get(cb, (np.inf, di)), (d, di))
        kept = set(sorted(nearest, key=lambda c: nearest[c])[:k])
        ranked = sorted(nearest[c][0] for c in nearest)
        if hub_ratio > 0 and len(ranked) >= k and ranked[k - 1] <= hub_ratio * ranked[0]:
            kept |= {cb for cb, d in every.items() if d <= hub_ratio * min(every.values())}
        for cb in kept:
            hits[(min(ca, cb), max(ca, cb))] += 1
    pairs = [(keys[i], keys[i]) for i in range(len(keys))]
    pairs += [(keys[a], keys[b]) for (a, b), n in hits.items() if n >= min_hits]
    return sorted(pairs)


def webs_by_clip(webs: list[dict], categories: dict[str, str], category: str | None) -> dict[str, list[dict]]:
    """The web records touching each clip, restricted to ``category`` (None: all), a dict filled
    record by record in the manifest's order: what ``store.webs.StoreWebs`` indexes in numpy."""
    out: dict[str, list[dict]] = {}
    for w in webs:
        if category is None or (categories.get(w["a"]) == category and categories.get(w["b"]) == category):
            out.setdefault(w["a"], []).append(w)
            if w["b"] != w["a"]:
                out.setdefault(w["b"], []).append(w)
    return out


def ref_web_states(web: MatchWeb, base: int) -> dict[str, np.ndarray]:
    """States, successors and branches of one web, numbered from ``base`` (``tasks.search.walk_graph``'s packing, one web).

    A bridge of fewer than two cells (two paths that share a cell: the junction's cells coincide)
    is a switch of path at that cell, not a step: its branches go from the shared cell of the
    leaving path straight to the successors of the joined path's cell (the next cell of that path
    and its bridges of two or more cells), so the shared cell is counted once and no step stays in
    place (KG04 §3.3 walks advance a row or a column per step; :func:`walk_graph` relies on it)."""
    n_cells = len(web.paths_cells)
    offs = web.paths_offsets
    nxt = np.arange(base + 1, base + n_cells + 1, dtype=np.int64)
    nxt[offs[1:][np.diff(offs) > 0] - 1] = -1
    lens = np.diff(web.bridges_offsets)
    inner = np.maximum(lens - 2, 0)
    inner_start = base + n_cells + np.cumsum(inner) - inner
    from_state = base + offs[web.bridges[:, 0]] + web.bridges[:, 1]
    to_state = base + offs[web.bridges[:, 2]] + web.bridges[:, 3]
    keep = np.ones(len(web.bridges_cells), bool)
    keep[web.bridges_offsets[:-1][lens > 0]] = False
    keep[web.bridges_offsets[1:][lens > 0] - 1] = False
    inner_cells = web.bridges_cells[keep]
    n_inner = int(inner.sum())
    inner_nxt = np.arange(base + n_cells + 1, base + n_cells + n_inner + 1, dtype=np.int64)
    last_inner = (inner_start + inner - 1)[inner > 0] - (base + n_cells)
    inner_nxt[last_inner] = to_state[inner > 0]
    # a switch (bridge of < 2 cells) leads to what follows the joined cell: its path's next cell and
    # the proper bridges leaving it
    switch = (lens < 2) | (web.paths_cells[from_state - base] == web.paths_cells[to_state - base]).all(axis=1)
    proper = ~switch
    b_from, b_to = from_state[proper], np.where(inner > 0, inner_start, to_state)[proper]
    if switch.any():
        sw_to = to_state[switch]
        b_from, b_to = _with_switches(b_from, b_to, from_state[switch], sw_to, nxt[sw_to - base])
    return {
        "cells": np.concatenate([web.paths_cells, inner_cells]).astype(np.int32),
        "values": np.concatenate([web.paths_values, web.bridges_values[keep]]).astype(np.float64),
        "nxt": np.concatenate([nxt, inner_nxt]),
        "branch_from": b_from.astype(np.int64),
        "branch_to": b_to.astype(np.int64),
        "path_first": base + offs[:-1],
        "path_last": base + offs[1:] - 1,
    }


def ref_walk_graph(webs: list[tuple[str, MatchWeb]]) -> WalkGraph:
    """``tasks.search.walk_graph`` one web at a time: each web's states numbered from the count
    so far (its path cells, then its bridge interiors), three-key sort into (web, row, col)
    order, values as float64 (the vectorised packing's float32 values widen to these exactly)."""
    n_frames, rate = webs[0][1].shape[0], float(webs[0][1].rate)  # the webs of one clip: checked by walk_graph
    parts, base = [], 0
    for other, w in webs:
        try:
            _check_web(w)
        except ValueError as exc:
            raise ValueError(f"match web with {other!r}: {exc}; run motionweb index to recompute it") from None
        s = ref_web_states(w, base)
        parts.append(s)
        base += len(s["cells"])
    cat = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    web_of = np.concatenate([np.full(len(p["cells"]), i, np.int64) for i, p in enumerate(parts)])
    rows, cols = cat["cells"][:, 0], cat["cells"][:, 1]
    # renumber the states by (web, row, col); ties keep the packing order
    order = np.lexsort((cols, rows, web_of))  # three keys, where walk_graph sorts one
    return ref_graph_of({**cat, "web_of": web_of}, order, n_frames, rate, tuple(o for o, _ in webs))


def ref_graph_of(cat: dict[str, np.ndarray], order: np.ndarray, n_frames: int, rate: float,
              others: tuple[str, ...]) -> WalkGraph:
    """``tasks.search._renumbered`` with numpy sorts: the :class:`WalkGraph` of packed states ``cat``
    (``_packed_states``'s arrays) renumbered by ``order`` (the states in (web, row, col) order):
    successors and branches renumbered (steps that do not advance dropped), the branch offsets,
    the row-start table. O(states · log states)."""
    base = len(cat["cells"])
    web_of = cat["web_of"]
    rows, cols = cat["cells"][:, 0], cat["cells"][:, 1]
    new = np.empty(base, np.int64)
    new[order] = np.arange(base)
    nxt = cat["nxt"][order]
    nxt = np.where(nxt >= 0, new[np.maximum(nxt, 0)], -1)
    # every step must go up and/or right (row + col grows: the walk's topological order, _collect;
    # rows never fall: the band of rows a..b, _nearest): a step of a malformed web that does not is
    # dropped, so the compiled walks only ever see a DAG within their bands
    r_new, c_new = rows[order].astype(np.int64), cols[order].astype(np.int64)

    def advances(u: np.ndarray, v: np.ndarray) -> np.ndarray:
        return (r_new[v] >= r_new[u]) & (c_new[v] >= c_new[u]) & (r_new[v] + c_new[v] > r_new[u] + c_new[u])

    bad_nxt = (nxt >= 0) & ~advances(np.arange(base), np.maximum(nxt, 0))
    nxt[bad_nxt] = -1
    b_from, b_to = new[cat["branch_from"]], new[cat["branch_to"]]
    good = advances(b_from, b_to)
    dropped = int(bad_nxt.sum()) + int((~good).sum())
    b_from, b_to = b_from[good], b_to[good]
    by_from = np.argsort(b_from, kind="stable")  # bridges by new from-state, packing order kept
    branch_off = np.zeros(base + 1, np.int64)
    np.cumsum(np.bincount(b_from, minlength=base), out=branch_off[1:])
    # the earliest row-r cell of each path crossing row r: a path cell whose predecessor on the path
    # lies in a lower row (or that starts the path) starts the rows above that predecessor's up to its own
    first, last = cat["path_first"], cat["path_last"]
    first, last = first[last >= first], last[last >= first]
    is_path = np.zeros(base, bool)
    is_path[np.repeat(first, last - first + 1) + _ranges(last - first + 1)] = True
    prev_row = np.full(base, -1, np.int64)
    prev_row[1:] = rows[:-1]
    prev_row[first] = rows[first] - 1
    entry = np.nonzero(is_path & (rows > prev_row))[0]
    n_rows = rows[entry] - prev_row[entry]
    e_state = np.repeat(entry, n_rows)
    e_row = rows[e_state] - _ranges(n_rows)
    e_key = web_of[e_state] * n_frames + e_row
    e_order = np.lexsort((e_state, e_key))  # by (web, row), then packing (= path) order
    start_off = np.searchsorted(e_key[e_order], np.arange(len(others) * n_frames + 1)).astype(np.int64)
    key = web_of[order] * (n_frames + 1) + rows[order]
    want = np.arange(len(others))[:, None] * (n_frames + 1) + np.arange(n_frames + 1)[None, :]
    return WalkGraph(
        rate=rate, n_frames=n_frames, others=others,
        rows=np.ascontiguousarray(rows[order]), cols=np.ascontiguousarray(cols[order]),
        values=cat["values"][order], nxt=_narrow(nxt), branch_off=_narrow(branch_off),
        branch_to=_narrow(b_to[by_from]), dropped_steps=dropped, web_rows=_narrow(np.searchsorted(key, want)),
        start_off=_narrow(start_off), starts=_narrow(new[e_state[e_order]]),
    )


def ref_cut_rows(cat: dict[str, np.ndarray], a: int, b: int) -> dict[str, np.ndarray]:
    """Reference for ``tasks.search._packed_window``: the states of ``_packed_states`` ``cat`` (all
    of them, numbered) that a walk of rows within a..b may use, cut with numpy masks: those of
    rows a..b plus each path's last cell before row a when its next cell lies in rows ≥ a,
    renumbered in the same order; steps to states left out end (``nxt`` −1) or are dropped
    (branches)."""
    cells, pf, pl = cat["cells"], cat["path_first"], cat["path_last"]
    r = cells[:, 0]
    keep = (r >= a) & (r <= b)
    n_path = int(pl[-1]) + 1 if len(pl) else 0
    if n_path > 1:
        ends = np.zeros(n_path, bool)
        ends[pl[pl >= pf]] = True
        keep[:n_path - 1] |= ~ends[:-1] & (r[:n_path - 1] < a) & (r[1:n_path] >= a)
    before = np.concatenate([[0], np.cumsum(keep)])
    new = before[:-1]
    nxt = cat["nxt"][keep]
    ok = nxt >= 0
    ok[ok] = keep[nxt[ok]]
    nxt = np.where(ok, new[np.where(ok, nxt, 0)], -1)
    bf, bt = cat["branch_from"], cat["branch_to"]
    both = keep[bf] & keep[bt]
    return {"cells": cells[keep], "values": cat["values"][keep], "nxt": nxt, "web_of": cat["web_of"][keep],
            "branch_from": new[bf[both]], "branch_to": new[bt[both]],
            "path_first": before[pf], "path_last": before[pl + 1] - 1}
