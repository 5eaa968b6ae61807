"""The index flow on a Dask cluster started separately (issue 25, part 6): ``dask scheduler`` and
``dask worker`` processes on loopback, the config's ``dask.address`` pointing at them. The webs
are the same objects (same keys, same checksums) as those a local cluster computes."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml


def _wait_for(path: Path, proc: subprocess.Popen, timeout: float = 120.0) -> dict:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        if proc.poll() is not None:
            raise RuntimeError(f"dask scheduler exited with {proc.returncode}")
        try:
            return json.loads(path.read_text())
        except (OSError, ValueError):
            time.sleep(0.2)
    raise TimeoutError("the dask scheduler did not write its file")


@pytest.fixture
def external_cluster(tmp_path: Path):
    """A scheduler and one worker (two processes of their own, loopback); the scheduler's address."""
    sched_file = tmp_path / "scheduler.json"
    dask = [sys.executable, "-m", "dask"]
    procs = [subprocess.Popen([*dask, "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                               "--scheduler-file", str(sched_file)],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    try:
        info = _wait_for(sched_file, procs[0])
        procs.append(subprocess.Popen([*dask, "worker", info["address"], "--nthreads", "1", "--nworkers", "1",
                                       "--no-dashboard", "--host", "127.0.0.1"],
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        from distributed import Client

        with Client(info["address"], timeout=60) as c:
            c.wait_for_workers(1, timeout=120)
        yield info["address"]
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in procs:
            try:
                p.wait(30)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()


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
