"""Shared fixtures: the real-data folder (skipped with a reason where absent)."""

from __future__ import annotations

from pathlib import Path

import pytest
from motionweb.store.datasets import ENV_VAR, mocap_root


@pytest.fixture(scope="session")
def mocap_dir() -> Path:
    root = mocap_root()
    if not root.is_dir():
        pytest.skip(f"real motion capture not found at {root} (set {ENV_VAR} to its folder)")
    return root


@pytest.fixture(scope="session")
def deepmimic_dir(mocap_dir: Path) -> Path:
    d = mocap_dir / "deepmimic"
    if not (d / "humanoid.urdf").is_file():
        pytest.skip(f"DeepMimic clips not found under {d} (set {ENV_VAR})")
    return d


@pytest.fixture(scope="session")
def cmu_dir(mocap_dir: Path) -> Path:
    """The CMU folder of the real data (``manifest.csv``, ``asf_amc/``, ``bvh/``)."""
    d = mocap_dir / "cmu"
    if not (d / "manifest.csv").is_file():
        pytest.skip(f"CMU files not found under {d} (set {ENV_VAR})")
    return d


@pytest.fixture(scope="session")
def prefect_harness():
    """Prefect's test harness (a temporary API server) once per session, heartbeats off."""
    from prefect.settings import PREFECT_FLOWS_HEARTBEAT_FREQUENCY, temporary_settings
    from prefect.testing.utilities import prefect_test_harness

    with prefect_test_harness(server_startup_timeout=300), \
            temporary_settings({PREFECT_FLOWS_HEARTBEAT_FREQUENCY: None}):
        yield
