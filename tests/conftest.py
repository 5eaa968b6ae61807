"""Shared fixtures: the real-data folder (skipped with a reason where absent)."""

from __future__ import annotations

import atexit
import os
import shutil
import tempfile
from pathlib import Path

import pytest
from hypothesis import settings
from motionweb.store.datasets import ENV_VAR, mocap_root
from motionweb.store.filecache import CACHE_ENV

# property-based tests draw the same examples on every run (CI included): a failure they find is
# reproducible, never a one-off of a random seed; HYPOTHESIS_PROFILE=explore draws new ones
settings.register_profile("repeatable", derandomize=True, database=None)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "repeatable"))

# motionweb's file caches (the app's packed walk graphs, store/filecache.py) in a folder of this
# run, never the user's: a test that needs them empty makes its own
os.environ[CACHE_ENV] = tempfile.mkdtemp(prefix="motionweb-test-cache-")
atexit.register(shutil.rmtree, os.environ[CACHE_ENV], True)
# Prefect's home (its local database, ~6 MB) for the flow runs made in this process: one folder of
# this run, removed at its end (a test that runs a CLI in a child gives it a tmp_path of its own)
if "PREFECT_HOME" not in os.environ:  # a home the caller set is theirs, used and kept
    os.environ["PREFECT_HOME"] = tempfile.mkdtemp(prefix="motionweb-test-prefect-")
    atexit.register(shutil.rmtree, os.environ["PREFECT_HOME"], True)


@pytest.fixture(scope="session")
def mocap_dir() -> Path:
    root = mocap_root()
    if not root.is_dir():
        pytest.skip(f"real motion capture not found at {root} (set {ENV_VAR} to its folder)")
    return root


def _real_set(root: Path, name: str, marker: str, what: str) -> Path:
    """The set ``root / name`` of the real data, skipping the test where its ``marker`` file is absent."""
    d = root / name
    if not (d / marker).is_file():
        pytest.skip(f"{what} not found under {d} (set {ENV_VAR})")
    return d


@pytest.fixture(scope="session")
def deepmimic_dir(mocap_dir: Path) -> Path:
    return _real_set(mocap_dir, "deepmimic", "humanoid.urdf", "DeepMimic clips")


@pytest.fixture(scope="session")
def cmu_dir(mocap_dir: Path) -> Path:
    """The CMU folder of the real data (``manifest.csv``, ``asf_amc/``, ``bvh/``)."""
    return _real_set(mocap_dir, "cmu", "manifest.csv", "CMU files")


@pytest.fixture(scope="session")
def cmu16(cmu_dir: Path) -> Path:
    """CMU subject 16's ASF/AMC folder (``16.asf``, ``16_01.amc`` ... ``16_58.amc``)."""
    return _real_set(cmu_dir / "asf_amc", "16", "16.asf", "CMU subject 16")


@pytest.fixture(scope="session")
def prefect_harness():
    """Prefect's test harness (a temporary API server) once per session, heartbeats off."""
    from prefect.settings import PREFECT_FLOWS_HEARTBEAT_FREQUENCY, temporary_settings
    from prefect.testing.utilities import prefect_test_harness

    with prefect_test_harness(server_startup_timeout=300), \
            temporary_settings({PREFECT_FLOWS_HEARTBEAT_FREQUENCY: None}):
        yield


def pytest_collection_modifyitems(config, items) -> None:
    """Mark every test of the pure stages (tests/tasks, tests/store: they call the compiled
    kernels directly) ``compiled``: .ci/run runs those a second time with numba's bounds checking
    on (issue 22)."""
    here = Path(__file__).parent
    for item in items:
        parts = Path(str(item.path)).relative_to(here).parts if Path(str(item.path)).is_relative_to(here) else ()
        if parts and parts[0] in ("tasks", "store"):
            item.add_marker(pytest.mark.compiled)
