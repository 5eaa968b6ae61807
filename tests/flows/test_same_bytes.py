"""Same bytes whatever the workers: the demo (two of its categories, two clips each) indexed with
two thread workers (sharing this process's multi-threaded BLAS) and with one process worker
(one BLAS thread) gives byte-identical features and webs."""

from __future__ import annotations

import shutil
from pathlib import Path

from motionweb.flows.config import load_config, packaged_config, resolve_paths
from motionweb.flows.index import index_library
from motionweb.store.demo.corpus import write_demo_corpus
from motionweb.store.generations import load_generation
from motionweb.store.zarr_store import MotionStore


def feature_chunks(store: Path) -> dict[str, bytes]:
    return {p.relative_to(store).as_posix(): p.read_bytes()
            for p in sorted((store / "features").rglob("c/*")) if p.is_file()}


def test_threads_and_processes_write_the_same_bytes(prefect_harness, tmp_path: Path) -> None:
    corpus = tmp_path / "corpus"
    base = load_config(packaged_config("demo.yaml"))
    write_demo_corpus(corpus, seed=base.demo.seed, variants_per_category=2, fps=base.demo.fps)
    for folder in corpus.iterdir():
        if folder.name not in ("sit", "walk"):
            shutil.rmtree(folder)
    gens = {}
    for kind, processes, workers in (("threads", False, 2), ("processes", True, 1)):
        data = base.model_dump(mode="json")
        data["corpus"]["path"] = str(corpus)
        data["store"]["path"] = str(tmp_path / kind)
        data["dask"] = {**data["dask"], "processes": processes, "n_workers": workers}
        cfg = resolve_paths(type(base).model_validate(data), tmp_path)
        summary = index_library(cfg)
        assert summary["pairs"] == summary["pairs_computed"] == 6, summary
        gens[kind] = load_generation(MotionStore(cfg.store.path))
    ref = gens["threads"]
    assert len(ref.checksums) == 6 + 4  # every web and feature object has its SHA-256
    for kind in ("processes",):
        assert gens[kind].checksums == ref.checksums, kind  # each object's bytes, byte for byte
        assert [w["key"] for w in gens[kind].webs] == [w["key"] for w in ref.webs]
        assert gens[kind].stats["chains"] == ref.stats["chains"]
    assert feature_chunks(tmp_path / "threads") == feature_chunks(tmp_path / "processes")
