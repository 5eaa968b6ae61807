"""Damaged stores, housekeeping and odd corpora through the index flow and `motionweb verify` / `gc`."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from fixtures import wiggle
from motionweb.flows.commands.cli import app
from motionweb.flows.config import Config, load_config, resolve_paths
from motionweb.flows.index import format_summary, index_library
from motionweb.store.bvh import write_bvh
from motionweb.store.generations import check_current, current_id, generation_ids, load_generation
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
    assert current_id(store) == first["generation"]  # readers go on with the last intact generation
    assert "falling back to generation" in caplog.text
    r = runner.invoke(app, ["verify", str(cfg_path)])  # the store is damaged: verify says which file
    assert r.exit_code == 1 and f"generations/{second['generation']}.json" in r.output, r.output
    assert "motionweb index" in r.output and "Traceback" not in r.output, r.output
    third = index_library(cfg)  # the store is not stuck: a new complete generation
    assert "is truncated" in third["repaired"] and third["generation"] not in (first["generation"],
                                                                                second["generation"])
    assert current_id(store) == third["generation"] and load_generation(store).stats["clips"] == 4
    assert runner.invoke(app, ["verify", str(cfg_path)]).exit_code == 0
    (root / "current").write_text("not json")
    assert current_id(store) == third["generation"]


# ---------------------------------------------------------------- the pointer is part of the store
def demo_copy(app_store: Path, tmp_path: Path) -> tuple[Path, MotionStore, str]:
    """A copy of the small demo store of ``tests/flows/conftest.py`` (config, corpus, store),
    indexed again where it lies (its paths are recorded) and with that one generation only:
    (its config path, the store, its current generation)."""
    import shutil

    from motionweb.store.generations import gc

    work = tmp_path / "work"
    shutil.copytree(app_store.parent, work, ignore=shutil.ignore_patterns("out", "disc*"))
    index_library(load_config(work / "config.yaml"))
    store = MotionStore(str(work / "store"))
    gc(store, keep=1)
    assert len(generation_ids(store)) == 1
    return work / "config.yaml", store, check_current(store)


def damage(store_dir: Path, kind: str, gen_id: str) -> str:
    """Damage a store's pointer or current manifest; returns the damaged file's key."""
    pointer, manifest = store_dir / "current", store_dir / "generations" / f"{gen_id}.json"
    if kind == "truncated pointer":
        pointer.write_bytes(pointer.read_bytes()[:17])
    elif kind == "deleted pointer":
        pointer.unlink()
    elif kind == "garbage pointer":
        pointer.write_bytes(os.urandom(64).replace(b"{", b"x"))
    elif kind == "pointer to a missing generation":
        pointer.write_text(json.dumps({"generation": "20991231T000000000000Z-00dead"}))
    elif kind == "truncated manifest":
        manifest.write_bytes(manifest.read_bytes()[:200])
    elif kind == "edited manifest":  # still valid JSON: found by the checksum in the pointer
        data = json.loads(manifest.read_text())
        data["clips"] = data["clips"][1:]
        manifest.write_text(json.dumps(data))
    else:
        raise AssertionError(kind)
    return "current" if "pointer" in kind else f"generations/{gen_id}.json"


DAMAGE = ["truncated pointer", "deleted pointer", "garbage pointer", "pointer to a missing generation",
          "truncated manifest", "edited manifest"]


def search_args(cfg_path: Path, out: Path) -> list[str]:
    return ["search", str(cfg_path), "--clip", "walk_00", "--start", "1", "--end", "2.5", "--quantile", "0.8",
            "--out", str(out)]


@pytest.mark.parametrize("kind", DAMAGE)
def test_damaged_pointer_fails_verify_and_index_repairs_it(app_store, tmp_path: Path, kind: str,
                                                           caplog) -> None:
    cfg_path, store, gen_id = demo_copy(app_store, tmp_path)
    key = damage(Path(store.url), kind, gen_id)

    r = runner.invoke(app, ["verify", str(cfg_path)])
    assert r.exit_code == 1 and "Traceback" not in r.output, r.output
    assert f"{store.url}: object {key} " in r.output and "motionweb index" in r.output, r.output
    assert "never indexed" not in r.output
    assert runner.invoke(app, ["gc", str(cfg_path)]).exit_code == 1  # nothing removed from a damaged store
    assert (Path(store.url) / "generations" / f"{gen_id}.json").exists()

    # readers: the pointer's damage falls back to the intact generation, with a warning; a damaged
    # manifest (the only generation) is a one-line error that says to run motionweb index
    r = runner.invoke(app, search_args(cfg_path, tmp_path / "out"))
    assert "Traceback" not in r.output, r.output
    if key == "current":
        assert r.exit_code == 0 and f"generation {gen_id}" in r.output, r.output
        assert "falling back to generation" in caplog.text and "motionweb index" in caplog.text
    else:
        assert r.exit_code == 2 and key in r.output and "motionweb index" in r.output, r.output
        assert "never indexed" not in r.output

    summary = index_library(load_config(cfg_path))
    assert key in summary["repaired"] and key in format_summary(summary)
    if key == "current":  # the pointer names the intact generation again: nothing recomputed
        assert summary["generation"] == gen_id and summary["pairs_computed"] == 0
    else:  # a fresh generation replaces the damaged manifest (its content-addressed objects reused)
        assert summary["generation"] != gen_id and summary["pairs_computed"] == 0
    assert check_current(store) == summary["generation"]
    r = runner.invoke(app, ["verify", str(cfg_path)])
    assert r.exit_code == 0 and ", 0 missing or damaged" in r.output, r.output
    r = runner.invoke(app, search_args(cfg_path, tmp_path / "out"))
    assert r.exit_code == 0 and f"generation {summary['generation']}" in r.output, r.output
    assert index_library(load_config(cfg_path))["repaired"] == ""  # repaired once


@pytest.mark.parametrize("kind", ["garbage pointer", "edited manifest"])
def test_the_app_reads_around_a_damaged_pointer(app_store, tmp_path: Path, kind: str) -> None:
    """The service's engine (through ``current_id``): a damaged pointer serves the intact
    generation; with no intact generation every request gets the error naming the file."""
    from motionweb.flows.app.engine import Engine
    from motionweb.store.generations import PointerError

    cfg_path, store, gen_id = demo_copy(app_store, tmp_path)
    key = damage(Path(store.url), kind, gen_id)
    engine = Engine(load_config(cfg_path), warm=False)
    if key == "current":
        assert engine.current().gen.id == gen_id
    else:
        with pytest.raises(PointerError, match="motionweb index") as info:
            engine.current()
        assert info.value.key == key and "never indexed" not in str(info.value)


@pytest.mark.parametrize("kind", ["truncated pointer", "truncated manifest"])
def test_repair_run_of_the_cli_prints_no_traceback(app_store, tmp_path: Path, kind: str) -> None:
    """`motionweb index` as a user runs it (its own process and Prefect server): it repairs the
    store, exits 0 and prints no traceback, neither of the flow nor of Prefect's shutdown."""
    import subprocess
    import sys

    cfg_path, store, gen_id = demo_copy(app_store, tmp_path)
    key = damage(Path(store.url), kind, gen_id)
    env = {k: v for k, v in os.environ.items() if not k.startswith("PREFECT_")}
    r = subprocess.run([sys.executable, "-m", "motionweb.flows.commands.cli", "index", str(cfg_path), "--no-progress"],
                       check=False, capture_output=True, text=True, timeout=600, env=env, cwd=tmp_path)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "Traceback" not in r.stderr and "Traceback" not in r.stdout, r.stderr
    assert f"repaired: {key} " in r.stdout, r.stdout
    r = runner.invoke(app, ["verify", str(cfg_path)])
    assert r.exit_code == 0 and ", 0 missing or damaged" in r.output, r.output


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


def test_a_rerun_parses_only_the_clips_that_changed(prefect_harness, tmp_path: Path, monkeypatch) -> None:
    """The scan of a rerun describes the unchanged clips from the current generation's records
    (hashed, not parsed; ``flows.index.known_clips``), through the CLI's check without Prefect and
    through the flow; a changed clip is parsed, and indexed as a full scan would index it."""
    import motionweb.store.catalog as catalog
    from motionweb.flows.index import unchanged_summary

    corpus = small_corpus(tmp_path / "corpus")
    cfg, _ = config(tmp_path, corpus)
    first = index_library(cfg)
    parsed: list[str] = []
    real = catalog.read_motion
    monkeypatch.setattr(catalog, "read_motion", lambda path, **kw: parsed.append(Path(path).name) or real(path, **kw))
    assert unchanged_summary(cfg)["generation"] == first["generation"]
    assert index_library(cfg)["generation"] == first["generation"]
    assert parsed == []
    write_bvh(wiggle(50, 30.0, seed=9), corpus / "walk" / "w1.bvh")
    second = index_library(cfg)
    assert set(parsed) == {"w1.bvh"} and second["pairs_computed"] >= 1  # by the scan, then for its features
    monkeypatch.undo()
    gen = load_generation(MotionStore(cfg.store.path))
    full = {e.path: e for e in catalog.scan_corpus(corpus, cfg.corpus).entries}
    assert {c["path"]: (c["sha256"], c["frames"], c["skeleton"]) for c in gen.clips} == {
        p: (e.sha256, e.frames, e.skeleton) for p, e in full.items()}
