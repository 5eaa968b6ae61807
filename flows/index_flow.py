"""The ``index-library`` Prefect flow (design §1, §10): the run over :mod:`motionweb.flows.index`'s
plan, tasks and :func:`~motionweb.flows.index.finish`. It keeps Prefect's own decorator, so that
``motionweb serve`` can serve it from this module (``Flow.serve`` loads its entrypoint and expects a
``prefect.Flow``); the rest of the index lives in :mod:`motionweb.flows.index`, which imports no
Prefect (``index`` with nothing to do answers without it). Cost: one catalog scan and one pair plan
(both O(clips + pairs)), the Dask compute of what is missing, one commit.
"""

from __future__ import annotations

import time
from typing import Any

from motionweb.flows.config import Config, load_config
from motionweb.flows.index import (
    SMALL_RUN_CELLS,
    Chunk,
    ChunkPlan,
    ShortlistReport,
    catalog_task,
    commit_task,
    dask_scheduler,
    features_task,
    finish,
    frames_at,
    known_clips,
    plan_chunks,
    plan_task,
    repair_note,
    shortlist_task,
    webs_task,
    working_rate,
)
from motionweb.store.generations import Generation, current_generation, load_generation, repair_current
from motionweb.store.zarr_store import MotionStore
from prefect import flow, get_run_logger
from prefect.utilities.annotations import quote


@flow(name="index-library")
def index_library(config: str | Config) -> dict[str, Any]:
    """Index a motion library into match webs (design §1, §10); returns the run summary.

    ``config`` is a config file path or a :class:`Config`. Nothing is visible to readers until
    the final commit switches the store's ``current`` generation.
    """
    cfg = config if isinstance(config, Config) else load_config(config)
    # Large task arguments (chunk plans, generations: O(pairs) objects) are passed quoted: Prefect
    # otherwise walks every element of them to resolve futures and record task inputs, in Python,
    # which at 146,610 webs made the commit a serial tail of minutes (issue 25)
    logger = get_run_logger()
    t0 = time.perf_counter()
    timings: dict[str, float] = {}
    store = MotionStore(cfg.store.path)
    # a damaged pointer names the newest intact generation again; the check parses the manifest
    # whole, as current_generation then needs it (the lean parse, ~3 s at 146,610 webs, then a second)
    damage = repair_current(store, lean=False)
    if damage is None:
        prev = current_generation(store, strict=True)
    else:
        prev = load_generation(store, damage.fallback) if damage.fallback else None
    parent = prev.id if prev is not None else None
    repaired = "" if damage is None else repair_note(damage)
    if repaired:
        logger.warning("%s: %s", store.url, repaired)

    catalog = catalog_task(cfg, quote(known_clips(prev, cfg)))
    if not catalog.entries:
        raise ValueError(f"corpus {catalog.root} holds no readable clip ({len(catalog.errors)} unreadable "
                         "files): nothing to index")
    timings["catalog_s"] = time.perf_counter() - t0
    chunks = plan_chunks(catalog.entries, cfg.index.chunk_by)
    results: dict[str, dict[str, Any]] = {}
    failed: dict[str, str] = {}
    if cfg.index.shortlist.enabled:
        plans, shortlists = _shortlisted(cfg, chunks, prev, timings, failed)
    else:
        shortlists = None
        t = time.perf_counter()
        plans = plan_task(quote(chunks), cfg, quote(prev), store=quote(store))
        timings["plan_s"] = time.perf_counter() - t
    todo_cells = sum(j.cells for p in plans for j in p.todo)
    t = time.perf_counter()
    if any(p.todo or (shortlists is None and p.features_todo) for p in plans):
        with dask_scheduler(cfg.dask, small=todo_cells < SMALL_RUN_CELLS) as address:
            logger.info("dask scheduler %s; %d pairs (%.3g cells) to compute",
                        address, sum(len(p.todo) for p in plans), todo_cells)
            if shortlists is None:
                _features(plans, cfg, address, failed)
                timings["features_s"] = time.perf_counter() - t
            webs = [webs_task.submit(quote(p), cfg, address, set(failed)) for p in plans]
            for rec in (r for f in webs for r in f.result()):
                results[rec["key"]] = rec
    timings["compute_s"] = time.perf_counter() - t
    if shortlists is not None:  # the features were computed before the shortlist
        timings["compute_s"] += timings.get("features_s", 0.0)
    return finish(cfg, store, catalog, plans, results, failed, parent, prev, damage, timings, t0,
                  lambda gen: commit_task(quote(gen), cfg.store.path, quote(store)), shortlists)


def _features(plans: list[ChunkPlan], cfg: Config, address: str, failed: dict[str, str]) -> None:
    """Features of the clips of ``plans`` that lack them, on Dask; clips that failed into ``failed``."""
    feats = [features_task.submit(quote(p), cfg, address) for p in plans]
    for rec in (r for f in feats for r in f.result()):
        if "error" in rec:
            failed[rec["sha256"]] = rec["error"]


def _shortlisted(cfg: Config, chunks: list[Chunk], prev: Generation | None, timings: dict[str, float],
                 failed: dict[str, str]) -> tuple[list[ChunkPlan], dict[str, ShortlistReport]]:
    """A shortlist run's plans (``index.shortlist``): the features every clip lacks (on Dask, a
    cluster sized by the webs they could need: each new clip against every clip), then each
    chunk's shortlist from the stored features, then the pair plan of the shortlisted pairs."""
    t = time.perf_counter()
    first = plan_task(quote(chunks), cfg, quote(prev), stage="features")
    timings["plan_s"] = time.perf_counter() - t
    todo = [c for p in first for c in p.features_todo]
    if todo:
        t = time.perf_counter()
        rate = working_rate(cfg)
        upper = sum(frames_at(c, rate) for c in todo) * sum(frames_at(c, rate) for ch in chunks for c in ch.clips)
        with dask_scheduler(cfg.dask, small=upper < SMALL_RUN_CELLS) as address:
            _features(first, cfg, address, failed)
        timings["features_s"] = time.perf_counter() - t
    t = time.perf_counter()
    shortlists = shortlist_task(quote(chunks), cfg, set(failed), quote(prev))
    timings["shortlist_s"] = time.perf_counter() - t
    t = time.perf_counter()
    plans = plan_task(quote(chunks), cfg, quote(prev), quote(shortlists), stage="pairs")
    timings["plan_s"] += time.perf_counter() - t
    for p, f in zip(plans, first, strict=True):
        p.features_todo = f.features_todo
    return plans, shortlists
