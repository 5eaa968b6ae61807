"""The compiled kernels a run calls from Python, with their argument types, so that they can be
compiled ahead of their first call and in parallel (issue 23: ``motionweb demo`` cold in ≤ 30 s).

numba compiles a kernel on its first call and keeps the machine code in its on-disk cache
(``cache=True``, beside the module or in ``NUMBA_CACHE_DIR``). A fresh install has no cache, and a
run pays every compilation on the thread that first calls the kernel: ~20 s of LLVM on one core
for the BVH reader, the index and the search kernels, while numba's compiler lock keeps the other core idle. This
module names the kernels by what calls them (:data:`GROUPS`: the BVH reader, the index of KG04
§3.1-3.2, the search and registration of KG04 §3.3-4) with the signatures a run with the default config uses
(the features' ``float32``, int64 cells), and :func:`compile_share` compiles one share of them
into the cache; ``motionweb.flows.runtime.warmup`` runs the shares in parallel processes. A later call
with these types loads the cached code (milliseconds) instead of compiling; a call with other
types (a config with ``features.dtype: float64``) still compiles on first use, as before.

``tests/tasks/test_warm.py`` runs the index and a search after a warm-up in a fresh cache and
fails on any kernel compiled anew, printing its signature in this module's notation, so the table
follows the code.

Signature notation: one token per argument, ``f4 f8 i1 i4 i8 u1 b1`` for the scalars
``float32 float64 int8 int32 int64 uint8 bool``, ``[:]`` / ``[:,:]`` ... for a C-contiguous array
of that many dimensions (``r`` after it: read-only), ``list(T)`` for a reflected list of ``T``.

Cost: each kernel compiles once per machine (numba keys its cache on the CPU and its own
version); a share costs the sum of its kernels' compile times plus numba's per-process compile of
the built-ins they use (array creation, ~1 s), hence shares by module, see :func:`shares`. The
kernels copy arrays element by element rather than by slice assignment, whose shape-mismatch
message brought numba's string formatting into each of them (it had doubled the compile time).
"""

from __future__ import annotations

import importlib
import re
from typing import Any

#: (module, kernel, signature, rough compile seconds on this 2-core machine), per group
GROUPS: dict[str, tuple[tuple[str, str, str, float], ...]] = {
    # reading BVH clips and their forward kinematics (the features, KG04 §3.1): a command that
    # scans its corpus calls the reader, then the kinematics, before any warm-up share is done
    "read": (("motionweb.store.bvh", "_parse_frames", "u1[:]r i8 i8 f8[:,:] f8[:]", 0.8),
             ("motionweb.store.kinematics", "_fk_paths", "f8[:,:,:] f8[:,:,:] f8[:,:] i8[:] i8[:] f8[:,:,:] f8[:,:,:]",
              0.5)),
    # KG04 §3.1-3.2: frame distances, local minima, chains, bridges, refinement
    "index": (
        ("motionweb.tasks.distance", "_combine", "f4[:,:] f4[:,:] f4[:,:] f4[:] f4[:] f4[:,:]", 0.2),
        ("motionweb.tasks.distance", "_grid_kernel", "f4[:,:] f4[:,:] f4[:] f4[:,:] f4[:,:] f4[:] f4[:,:]", 1.0),
        ("motionweb.tasks.distance", "_shift_heights", "f8[:,:] f8[:,:] f8[:,:] f8[:] f8 f8[:,:] f4[:,:] f4[:,:]", 0.2),
        ("motionweb.tasks.matchweb.minima", "_local_minima", "f4[:,:]", 0.45),
        ("motionweb.tasks.matchweb.minima", "_valid_region", "f4[:,:] u1[:,:] f8", 0.5),
        ("motionweb.tasks.matchweb.minima", "_find_chains", "f4[:,:] u1[:,:] i8 i8", 0.9),
        ("motionweb.tasks.matchweb.bridges", "_find_bridges", "f4[:,:] b1[:,:] i8[:,:] i8[:] i8[:,:] i8[:] i8 i8",
         7.3),
        ("motionweb.tasks.matchweb.refine", "_mark_tiles", "i8[:,:] i8[:] f8 f8 i8 i8 i8[:,:]", 1.1),
        ("motionweb.tasks.matchweb.refine", "_alloc_tiles", "i8[:,:]", 0.3),
        ("motionweb.tasks.matchweb.refine", "_refine_chains",
         "i8[:,:] i8[:] f8 f8 i8 i8 i8 i8[:,:] f8[:,:,:] f4[:,:] f4[:,:] f4[:] f4[:,:] f4[:,:] f4[:] i8 i8", 13.2),
        ("motionweb.tasks.matchweb.refine", "_refine_bridges",
         ("i8[:,:] i8[:] i8[:,:] i8[:,:] i8[:] i8[:] i8[:,:] i8[:] f8 f8 i8 i8 i8 i8[:,:] f8[:,:,:] f4[:,:] f4[:,:] "
          "f4[:] f4[:,:] f4[:,:] f4[:] i8 i8"), 3.0),
    ),
    # KG04 §3.3-3.4: the match walk, redundancy removal, the match graph; §4 registration
    "search": (
        ("motionweb.tasks.search", "_walk",
         "i4[:] i4[:] f4[:] i4[:] i4[:] i4[:] i4[:,:] i4[:] i4[:] i8 i8 f8 i8[:] i8[:] i8[:] f8[:] f8[:] i8[:] i8[:]", 2.1),
        ("motionweb.tasks.search", "_pack_order", "i8[:] i4[:] i4[:] i8 i8 i8", 0.3),
        ("motionweb.tasks.search", "_renumbered", "i4[:] i4[:] i8[:] i8[:] i8[:] i8[:] i8[:] i8[:] i8[:] i8 i8", 0.8),
        ("motionweb.tasks.search", "_window_states", "i8[:] i4[:,:] f4[:] i8[:] i8[:,:] i8[:] i4[:,:] f4[:] i8[:] i8 i8", 0.8),
        ("motionweb.tasks.search", "_greedy_disjoint", "i8[:] i8[:] i8[:] f8", 0.2),
        ("motionweb.tasks.search", "_steps_ok", "i4[:] i4[:] i4[:] i4[:] i4[:] i8", 0.2),
        ("motionweb.tasks.search", "place_matches", "i8[:] i8[:] i8[:] i8[:,:] i8 f8 f8", 0.6),
        ("motionweb.tasks.distance", "_combine", "f8[:,:] f8[:,:] f8[:,:] f8[:] f8[:] f8[:,:]", 0.2),
        ("motionweb.tasks.distance", "_shift_heights", "f8[:,:] f8[:,:] f8[:,:] f8[:] f8 f8[:,:] f8[:,:] f8[:,:]", 0.2),
        ("motionweb.tasks.register", "_band_valid", "i8[:] i8[:] i8[:] f8[:] f8", 0.5),
        ("motionweb.tasks.matchweb.band", "best_state_total", "f8[:,:] i8", 0.1),
    ),
}

_SCALARS = {"f4": "float32", "f8": "float64", "i1": "int8", "i4": "int32", "i8": "int64", "u1": "uint8",
            "b1": "boolean"}
_TOKEN = re.compile(r"^(?:list\((?P<item>.+)\)|(?P<code>[a-z]\d)(?P<dims>\[[:,]*\])?(?P<ro>r)?)$")


def parse_type(token: str) -> Any:
    """One argument's numba type from the notation above (``"f4[:,:]"`` → ``Array(float32, 2, 'C')``)."""
    from numba.core import types as nt

    m = _TOKEN.match(token)
    if m is None or (m["code"] and m["code"] not in _SCALARS):
        raise ValueError(f"kernel signature token {token!r}: expected e.g. f8, i8[:], f4[:,:]r or list(i4[:,:])")
    if m["item"]:
        return nt.List(parse_type(m["item"]), reflected=False)
    scalar = getattr(nt, _SCALARS[m["code"]])
    if not m["dims"]:
        return scalar
    return nt.Array(scalar, m["dims"].count(":"), "C", readonly=bool(m["ro"]))


def format_type(tp: Any) -> str:
    """The notation of a numba argument type (the inverse of :func:`parse_type`; ``?repr`` for a type
    it cannot write)."""
    from numba.core import types as nt

    codes = {v: k for k, v in _SCALARS.items()} | {"bool": "b1"}
    if isinstance(tp, nt.Array) and tp.layout == "C" and str(tp.dtype) in codes:
        return codes[str(tp.dtype)] + "[" + ",".join(":" * tp.ndim) + "]" + ("" if tp.mutable else "r")
    if isinstance(tp, nt.List):
        return f"list({format_type(tp.dtype)})"
    return codes.get(str(tp), f"?{tp!r}")


def kernels(groups: list[str]) -> list[tuple[str, str, str, float]]:
    """The table's rows of ``groups`` (each row once; an unknown group is a ``ValueError``)."""
    unknown = sorted(set(groups) - set(GROUPS))
    if unknown:
        raise ValueError(f"unknown kernel groups {unknown}; known: {sorted(GROUPS)}")
    rows = [row for g in groups for row in GROUPS[g]]
    return list(dict.fromkeys(rows))


def shares(groups: list[str], n: int) -> list[list[tuple[str, str, str, float]]]:
    """``groups``' kernels in ``n`` shares of about equal compile time. A module's kernels stay in
    one share (they call the same helpers, which would otherwise compile in two processes); the
    modules go, longest first, to the share with the least so far (LPT). Each share then compiles
    its kernels in the table's order, so that what a command calls first (the BVH reader, then the
    frame distances) is cached first rather than after a long kernel of the same share."""
    rows_in_order = kernels(groups)
    by_module: dict[str, list[tuple[str, str, str, float]]] = {}
    for row in rows_in_order:
        by_module.setdefault(row[0], []).append(row)
    out: list[list[tuple[str, str, str, float]]] = [[] for _ in range(max(1, n))]
    load = [0.0] * len(out)
    for rows in sorted(by_module.values(), key=lambda r: -sum(x[3] for x in r)):
        i = load.index(min(load))
        out[i] += rows
        load[i] += sum(x[3] for x in rows)
    order = {row: k for k, row in enumerate(rows_in_order)}
    return [sorted(s, key=order.__getitem__) for s in out if s]


def compile_share(rows: list[tuple[str, str, str, float]]) -> int:
    """Compile ``rows`` into numba's cache (a row already cached is loaded, not compiled); the number
    of kernels done. Cost: the rows' compile times, once per machine."""
    for module, name, signature, _ in rows:
        kernel = getattr(importlib.import_module(module), name)
        kernel.compile(tuple(parse_type(t) for t in signature.split()))
    return len(rows)
