"""Producers run on Dask workers: features and match webs of a batch, written to the store.

They live apart from :mod:`motionweb.flows.index` so that worker processes import neither Prefect
(~5 s per worker) nor the flow; they take plain values (clip entries, keys, the config) and return
small records. Each clip's distance operands are cached per worker process.

Same bytes whatever the workers: a multi-threaded BLAS splits a GEMM's sums by its thread
count (measured: a distance grid computed with 1 and with 2 OpenBLAS threads differs by up to
1e-7), and Dask process workers run one BLAS thread while thread workers share the parent's
pool. So every producer pins the process to one BLAS thread before computing; the parallelism
is across workers. Features and webs are then identical with thread or process workers, any
worker count and any BLAS configuration (tests/flows/test_same_bytes.py).
"""

from __future__ import annotations

import logging
import time
from functools import lru_cache
from typing import TYPE_CHECKING, Any

import numpy as np
from motionweb.store.cache import LRU
from motionweb.store.catalog import ClipEntry, load_clip
from motionweb.store.keys import feature_digest
from motionweb.store.zarr_store import MotionStore
from motionweb.tasks.distance import ClipOperands
from motionweb.tasks.features import feature_set
from motionweb.tasks.matchweb.build import build_web_operands
from threadpoolctl import threadpool_limits

if TYPE_CHECKING:
    from motionweb.flows.config import Config

#: what a Dask worker logs, with a traceback, when the heartbeat it sent as its local cluster
#: closed finds the scheduler gone (distributed.worker.Worker.heartbeat): nothing a user can act on
HEARTBEAT_LOST = "Failed to communicate with scheduler during heartbeat"


class ShutdownHeartbeat(logging.Filter):
    """Drops :data:`HEARTBEAT_LOST` records (design §10, orchestration: the CLI's output is the tool's own)."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not record.getMessage().startswith(HEARTBEAT_LOST)


SHUTDOWN_HEARTBEAT = ShutdownHeartbeat()


def quiet_heartbeat(on: bool = True) -> None:
    """Add (``on``) or remove the :class:`ShutdownHeartbeat` filter on ``distributed.worker`` in
    this process: run on every worker of a local cluster, and in the process that owns it, just
    before the cluster closes (``flows.index.dask_scheduler``); idempotent."""
    log = logging.getLogger("distributed.worker")
    log.addFilter(SHUTDOWN_HEARTBEAT) if on else log.removeFilter(SHUTDOWN_HEARTBEAT)


@lru_cache(maxsize=1)
def pin_blas_threads() -> None:
    """One BLAS thread in this process from now on (see the module notes); idempotent."""
    threadpool_limits(1)


@lru_cache(maxsize=8)
def worker_store(url: str) -> MotionStore:
    return MotionStore(url)


#: the distance operands of the clips this worker process used last, least recently used dropped
#: first beyond ``index.operand_cache_mb`` (set by each batch; unbounded until then). Bounded by
#: bytes, not clips: a batch visits its columns clips in a cycle (pairs sorted by rows clip), so a
#: bound of 128 clips made every pair of a chunk of more clips (180 in the issue 25 corpus of
#: 381k frames) read and prepare its columns clip again.
_OPERANDS = LRU()


def clip_operands(url: str, sha: str, fdigest: str) -> dict[float, ClipOperands]:
    """A clip's distance operands by rate (:class:`~motionweb.tasks.distance.ClipOperands`), cached per worker:
    a clip appears in many pairs, and is read and prepared once, not once per pair (O(F·P) per clip
    and rate, about 48·F·P bytes kept)."""
    key = (url, sha, fdigest)
    ops = _OPERANDS.get(key)
    if ops is None:
        by_rate, weights = worker_store(url).read_features(sha, fdigest)
        ops = ClipOperands.by_rate(by_rate, weights)
        _OPERANDS.put(key, ops, sum(o.nbytes for o in ops.values()))
    return ops


def clear_operands() -> None:
    """Forget the cached operands (:func:`clip_operands`) of this process."""
    _OPERANDS.clear()


def web_counts(arrays: dict[str, Any]) -> dict[str, int]:
    """Chains and bridges of a web from its flat arrays (ragged: ``*_offsets`` hold N+1 bounds)."""

    def count(prefix: str) -> int:
        off = arrays.get(f"{prefix}_offsets")
        return max(0, len(off) - 1) if off is not None else 0

    return {"n_chains": count("paths"), "n_bridges": count("bridges")}


def compute_features_batch(clips: list[ClipEntry], cfg: Config, store_url: str) -> list[dict[str, Any]]:
    """Features of clips at every rate plus point weights, written to the store (design §3).

    Returns one small record per clip (``error`` when the clip cannot be read or featurized).
    """
    pin_blas_threads()
    store = worker_store(store_url)
    fdig = feature_digest(cfg)
    out = []
    for c in clips:
        t = time.perf_counter()
        try:
            motion = load_clip(c, cfg.corpus)
            by_rate, weights = feature_set(motion, cfg.features, up=cfg.corpus.up_axis)
            store.write_features(c.sha256, fdig, by_rate, weights,
                                 {"path": c.path, "skeleton": c.skeleton, "fps": c.fps})
            out.append({"sha256": c.sha256, "seconds": time.perf_counter() - t})
        except Exception as exc:  # noqa: BLE001 - a broken clip is recorded, the run goes on
            out.append({"sha256": c.sha256, "path": c.path, "error": f"{type(exc).__name__}: {exc}"})
    return out


def compute_web_batch(pairs: list[tuple[str, str, str, bool]], cfg: Config, store_url: str) -> list[dict[str, Any]]:
    """Match webs (KG04 §3.1-3.2) of ``(key, rows sha, columns sha, self pair)`` tuples.

    Takes both clips' operands from the worker's cache (read and prepared once per clip), builds
    each web coarse to fine and writes the batch's webs as one shard at the end (the full grid on
    the side with ``keep_grids``): a failed batch leaves nothing behind and is recomputed whole.
    Returns small records only.
    """
    pin_blas_threads()
    _OPERANDS.max_bytes = int(cfg.index.operand_cache_mb * 2**20)
    store = worker_store(store_url)
    fdig = feature_digest(cfg)
    rate = float(max(cfg.features.rates))
    out: list[dict[str, Any]] = []
    done: list[tuple[str, dict[str, np.ndarray], dict[str, Any]]] = []
    for key, a_sha, b_sha, self_pair in pairs:
        t = time.perf_counter()
        try:
            oa = clip_operands(store_url, a_sha, fdig)
            ob = oa if self_pair else clip_operands(store_url, b_sha, fdig)
            web = build_web_operands(oa, ob, cfg.matchweb, self_pair)
            arrays = web.to_arrays()
            grid = arrays.pop("grid", None)  # kept on the side (keep_grids), not part of the web
            meta = {"a_sha": a_sha, "b_sha": b_sha, "rate": rate,
                    "shape": [oa[rate].n_frames, ob[rate].n_frames], **web_counts(arrays)}
            done.append((key, arrays, meta))
            if grid is not None:
                store.write_grid(key, grid)
            out.append({"key": key, "seconds": time.perf_counter() - t, **meta})
        except Exception as exc:  # noqa: BLE001 - a failed pair is recorded, the run goes on
            out.append({"key": key, "error": f"{type(exc).__name__}: {exc}"})
    shards = store.write_webs(done)
    for rec in out:  # where each web is: the generation records it for readers (MotionStore.web_shard)
        if rec["key"] in shards:
            rec["shard"] = shards[rec["key"]]
    return out
