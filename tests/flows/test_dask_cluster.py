"""The index flow on a Dask cluster started separately (issue 25, part 6): ``dask scheduler`` and
``dask worker`` processes on loopback, the config's ``dask.address`` pointing at them. The webs
are the same objects (same keys, same checksums) as those a local cluster computes. The cluster
(``external_cluster``) is a fixture of ``conftest.py``: ``test_s3_store.py`` runs the index on it too."""

from __future__ import annotations

import shutil
from pathlib import Path

import yaml


def test_the_index_on_a_separately_started_cluster(prefect_harness, external_cluster: str, tmp_path: Path) -> None:
    from motionweb.flows.config import load_config
    from motionweb.flows.index import index_library
    from motionweb.store.demo.corpus import write_demo_corpus
    from motionweb.store.generations import load_generation
    from motionweb.store.zarr_store import MotionStore

    write_demo_corpus(tmp_path / "corpus", seed=7, variants_per_category=2, fps=30.0)
    for d in (tmp_path / "corpus").iterdir():
        if d.name not in ("walk", "jump"):
            shutil.rmtree(d)
    gens = {}
    for name, dask in (("remote", {"address": external_cluster}), ("local", {"processes": False})):
        cfg_path = tmp_path / f"{name}.yaml"
        cfg_path.write_text(yaml.safe_dump({"corpus": {"path": "corpus", "length_unit": "m"},
                                            "features": {"rates": [10.0, 30.0]}, "store": {"path": f"store-{name}"},
                                            "dask": dask, "output": f"out-{name}"}))
        summary = index_library(load_config(cfg_path))
        assert summary["pairs_computed"] == summary["pairs"] > 0 and not summary["broken"], summary
        gens[name] = load_generation(MotionStore(str(tmp_path / f"store-{name}")))
    remote, local = gens["remote"], gens["local"]
    assert sorted(w["key"] for w in remote.webs) == sorted(w["key"] for w in local.webs)
    assert remote.checksums == local.checksums  # the same bytes, computed by the other cluster
