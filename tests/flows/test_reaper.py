"""Services die with the CLI: kill only the main process, its descendants follow (flows/runtime/reaper.py)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from fixtures import tiny_index_config
from motionweb.flows.runtime.reaper import descendants

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the reaper reads /proc")


def _alive(procs: set[tuple[int, str]]) -> set[tuple[int, str]]:
    out = set()
    for pid, start in procs:
        try:
            with open(f"/proc/{pid}/stat") as fh:
                if fh.read().rsplit(")", 1)[1].split()[19] == start:
                    out.add((pid, start))
        except OSError:
            pass
    return out


def _wait_gone(procs: set[tuple[int, str]], timeout: float) -> set[tuple[int, str]]:
    deadline = time.monotonic() + timeout
    while _alive(procs) and time.monotonic() < deadline:
        time.sleep(0.2)
    return _alive(procs)


#: a parent that starts the watchdog and one long-lived child, then sleeps
PARENT = ("import subprocess, sys, time; from motionweb.flows.runtime.reaper import start_reaper; start_reaper(); "
          "subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(120)']); time.sleep(120)")


def _watched_parent() -> tuple[subprocess.Popen, set[tuple[int, str]]]:
    """:data:`PARENT` started, once its watchdog has seen its child: (the parent, its descendants)."""
    parent = subprocess.Popen([sys.executable, "-c", PARENT], start_new_session=True)
    deadline = time.monotonic() + 60
    while len(descendants(parent.pid)) < 2 and time.monotonic() < deadline:  # reaper + sleeper
        time.sleep(0.2)
    time.sleep(1.0)  # one poll of the reaper
    kids = descendants(parent.pid)
    assert len(kids) >= 2
    return parent, kids


def test_children_die_with_a_killed_parent() -> None:
    parent, kids = _watched_parent()
    os.kill(parent.pid, signal.SIGKILL)
    parent.wait()
    assert not _wait_gone(kids, 20), "descendants outlived their killed parent"


def test_a_zombie_is_dead_to_the_reaper() -> None:
    """A died but unreaped CLI (state Z) ends its watchdog's watch: its children are ended."""
    parent, kids = _watched_parent()
    try:
        os.kill(parent.pid, signal.SIGKILL)  # not waited for: a zombie while we look
        left = _wait_gone(kids, 20)
        with open(f"/proc/{parent.pid}/stat") as fh:
            assert fh.read().rsplit(")", 1)[1].split()[0] == "Z"
        assert not left, "the watchdog took the zombie for alive"
    finally:
        if parent.poll() is None:
            os.kill(parent.pid, signal.SIGKILL)
        parent.wait()


def test_killing_the_cli_ends_its_prefect_server_and_workers(tmp_path: Path) -> None:
    tiny_index_config(tmp_path)
    env = {k: v for k, v in os.environ.items() if not k.startswith("PREFECT_API")}
    env["PREFECT_HOME"] = str(tmp_path / "prefect")
    cli = subprocess.Popen([sys.executable, "-m", "motionweb.flows.commands.cli", "index", str(tmp_path / "c.yaml"),
                            "--no-progress"], env=env, start_new_session=True,
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        seen: set[tuple[int, str]] = set()
        deadline = time.monotonic() + 180
        while time.monotonic() < deadline and cli.poll() is None:
            seen |= descendants(cli.pid)
            if len(seen) >= 3:  # the reaper, Prefect's server and at least one Dask process
                break
            time.sleep(0.2)
        assert cli.poll() is None and len(seen) >= 3, "the CLI finished before its services were seen"
        time.sleep(1.0)
        seen |= descendants(cli.pid)
    finally:
        os.kill(cli.pid, signal.SIGKILL)
        cli.wait()
    assert not _wait_gone(seen, 30), "services outlived the killed CLI"
