"""Damaged stores, housekeeping and odd corpora through the index flow and `motionweb verify` / `gc`."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from fixtures import wiggle
from motionweb.flows.cli import app
from motionweb.flows.config import Config, resolve_paths
from motionweb.flows.index import index_library
from motionweb.store.bvh import write_bvh
from motionweb.store.generations import current_id, generation_ids, load_generation
from motionweb.store.zarr_store import MotionStore
from typer.testing import CliRunner

runner = CliRunner()


def small_corpus(root: Path) -> Path:
    (root / "walk").mkdir(parents=True)
    for k in range(3):
        write_bvh(wiggle(45 + 10 * k, 30.0, seed=k), root / "walk" / f"w{k}.bvh")
    return root


def config(tmp: Path, corpus: Path) -> tuple[Config, Path]:
    data = {"corpus": {"path": str(corpus), "length_unit": "m"}, "features": {"rates": [10.0, 20.0]},
            "store": {"path": str(tmp / "store")}, "dask": {"processes": False, "n_workers": 1},
            "output": str(tmp / "out")}
    path = tmp / "config.yaml"
    import yaml

    path.write_text(yaml.safe_dump(data))
    return resolve_paths(Config.model_validate(data), tmp), path


def chunk_files(folder: Path) -> list[Path]:
    return sorted(p for p in folder.rglob("c/*") if p.is_file())


def test_damage_is_found_and_recomputed(prefect_harness, tmp_path: Path) -> None:
    cfg, cfg_path = config(tmp_path, small_corpus(tmp_path / "corpus"))
    first = index_library(cfg)
    store_dir = Path(cfg.store.path)
    assert runner.invoke(app, ["verify", str(cfg_path)]).exit_code == 0

    shard_chunk = chunk_files(store_dir / "webs" / "shards")[0]
    data = bytearray(shard_chunk.read_bytes())
    data[len(data) // 2] ^= 0xFF  # one flipped byte in a web shard
    shard_chunk.write_bytes(bytes(data))
    feature_chunk = chunk_files(store_dir / "features")[0]
    feature_chunk.unlink()  # zarr would read the missing chunk back as zeros

    r = runner.invoke(app, ["verify", str(cfg_path)])
    assert r.exit_code == 1 and "Traceback" not in r.output, r.output
    assert "damaged: web walk/" in r.output and "damaged: features of walk/" in r.output, r.output

    again = index_library(cfg)  # recomputes what is damaged instead of committing it
    assert again["pairs_computed"] >= 1 and again["features_computed"] == 1, again
    assert again["pairs"] == first["pairs"] and again["chains"] == first["chains"]
    r = runner.invoke(app, ["verify", str(cfg_path)])
    assert r.exit_code == 0 and ", 0 missing or damaged" in r.output, r.output


def test_noop_reruns_do_not_grow_the_store_and_gc_cleans_leftovers(prefect_harness, tmp_path: Path) -> None:
    cfg, cfg_path = config(tmp_path, small_corpus(tmp_path / "corpus"))
    first = index_library(cfg)
    store = MotionStore(cfg.store.path)
    size = store.size_bytes()
    for _ in range(3):
        s = index_library(cfg)
        assert s["generation"] == first["generation"] and s["pairs_computed"] == 0
    assert generation_ids(store) == [first["generation"]]
    assert store.size_bytes() <= 1.2 * size

    # leftovers of a killed run: a temp pointer, an uncommitted manifest, an orphan shard
    root = Path(cfg.store.path)
    (root / "current.tmp-dead").write_text("{")
    (root / "generations" / "99999999T000000000000Z-dead00.json").write_text(
        (root / "generations" / f"{first['generation']}.json").read_text())
    store.write_webs([("webs/zz/orphan-orphan/" + first["params"]["webs"], {"x": wiggle(3, 30.0, 0).rotations}, {})])
    r = runner.invoke(app, ["gc", str(cfg_path), "--keep", "1"])
    assert r.exit_code == 0, r.output
    assert not (root / "current.tmp-dead").exists() and generation_ids(store) == [first["generation"]]
    assert not MotionStore(cfg.store.path).has("webs/zz/orphan-orphan/" + first["params"]["webs"])
    assert runner.invoke(app, ["verify", str(cfg_path)]).exit_code == 0


def test_damaged_current_manifest_falls_back(prefect_harness, tmp_path: Path, caplog) -> None:
    corpus = small_corpus(tmp_path / "corpus")
    cfg, cfg_path = config(tmp_path, corpus)
    first = index_library(cfg)
    write_bvh(wiggle(50, 30.0, seed=9), corpus / "walk" / "w9.bvh")
    second = index_library(cfg)
    root = Path(cfg.store.path)
    manifest = root / "generations" / f"{second['generation']}.json"
    manifest.write_text(manifest.read_text()[:100])  # truncated
    store = MotionStore(cfg.store.path)
    assert current_id(store) == first["generation"]
    assert "falling back to generation" in caplog.text
    r = runner.invoke(app, ["verify", str(cfg_path)])
    assert r.exit_code == 0 and first["generation"] in r.output, r.output
    third = index_library(cfg)  # the store is not stuck: a new complete generation
    assert current_id(store) == third["generation"] and load_generation(store).stats["clips"] == 4
    (root / "current").write_text("not json")
    assert current_id(store) == third["generation"]


def test_empty_corpus_is_refused(prefect_harness, tmp_path: Path) -> None:
    (tmp_path / "corpus").mkdir()
    (tmp_path / "corpus" / "notes.txt").write_text("no clip here")
    _cfg, cfg_path = config(tmp_path, tmp_path / "corpus")
    r = runner.invoke(app, ["index", str(cfg_path), "--no-progress"])
    assert r.exit_code == 2 and "holds no readable clip" in r.output and "Traceback" not in r.output, r.output
    assert not (tmp_path / "store" / "current").exists()


def test_corpus_through_symlinks(tmp_path: Path) -> None:
    from motionweb.store.catalog import scan_corpus

    real = small_corpus(tmp_path / "real")
    corpus = tmp_path / "corpus"
    corpus.mkdir()
    os.symlink(real / "walk", corpus / "walk")
    os.symlink(corpus, corpus / "walk_loop")  # a loop: walked once
    cat = scan_corpus(corpus)
    assert sorted(e.path for e in cat.entries) == ["walk/w0.bvh", "walk/w1.bvh", "walk/w2.bvh"]
    assert {e.category for e in cat.entries} == {"walk"} and not cat.errors
    assert json.loads(cat.to_json())["clips"]


@pytest.fixture(autouse=True)
def _quiet(monkeypatch):
    for var, value in [("PREFECT_LOGGING_LEVEL", "WARNING"), ("DASK_LOGGING__DISTRIBUTED", "warning")]:
        monkeypatch.setenv(var, value)
