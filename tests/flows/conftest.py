"""A tiny indexed demo store for the service's tests (walks and runs, three of each)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import yaml


@pytest.fixture(scope="session")
def app_store(prefect_harness, tmp_path_factory) -> Path:
    """The config path of an indexed store of six demo clips (walk, run) at 30 fps."""
    from motionweb.flows.config import load_config
    from motionweb.flows.index import index_library
    from motionweb.store.demo.corpus import write_demo_corpus

    work = tmp_path_factory.mktemp("app")
    write_demo_corpus(work / "corpus", seed=7, variants_per_category=3, fps=30.0)
    for d in (work / "corpus").iterdir():
        if d.name not in ("walk", "run"):
            shutil.rmtree(d)
    cfg_path = work / "config.yaml"
    cfg_path.write_text(yaml.safe_dump({"corpus": {"path": "corpus", "length_unit": "m"},
                                        "features": {"rates": [10.0, 30.0]}, "store": {"path": "store"},
                                        "dask": {"processes": False}, "output": "out"}))
    index_library(load_config(cfg_path))
    return cfg_path
