"""A tiny indexed demo store for the service's tests (walks and runs, three of each)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import threading
import time
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


@pytest.fixture(scope="session")
def app_space(app_store) -> str:
    """The id of a motion space stored in ``app_store``: the right hand's position 0.75 s into
    walk_00 1-2.5 s over that query's matches (KG04 §4, a 3-D parameter), 300 samples."""
    from motionweb.flows.commands.requests import SpaceRequest
    from motionweb.flows.config import load_config
    from motionweb.flows.space import parameterize

    res = parameterize(load_config(app_store), SpaceRequest(clip="walk_00", start=1.0, end=2.5, quantile=0.8,
                                                           param="position:RightHand@0.75", samples=300,
                                                           out=str(app_store.parent / "out")))
    return res["id"]


@pytest.fixture(scope="module")
def running(app_store, tmp_path_factory):
    """A real service of ``app_store`` (uvicorn in a thread, no Prefect recording) with its
    discovery file in a folder of the module's own (``MOTIONWEB_APP_DIR``)."""
    from motionweb.flows.app.client import discovery_file
    from motionweb.flows.app.server import Service
    from motionweb.flows.config import load_config

    cfg = load_config(app_store)
    os.environ["MOTIONWEB_APP_DIR"] = str(tmp_path_factory.mktemp("disc"))
    svc = Service(cfg, port=0, record=False)
    t = threading.Thread(target=svc.run, daemon=True)
    t.start()
    for _ in range(200):
        if svc.server.started:
            break
        time.sleep(0.05)
    yield svc
    svc.stop()
    t.join(10)
    assert not discovery_file(cfg.store.path).exists()
    del os.environ["MOTIONWEB_APP_DIR"]


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
