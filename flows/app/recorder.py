"""Prefect for the service: one API server started or reused, every answered query recorded as a
flow run on it (visible in Prefect's UI with its parameters, log line and outcome).

Choice made here: a Prefect flow run costs 0.3-1 s of API round trips on this 2-core machine
(measured: an empty flow, heartbeats off, local server), ten times the service's latency budget
for a warm search (≤ 100 ms), so the service answers from memory first and a background thread
records the query as a flow run of :func:`app_query` right after; a full queue drops records
(counted in :attr:`Recorder.dropped`) rather than slowing the service.
"""

from __future__ import annotations

import logging
import os
import queue
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

from motionweb.flows.runtime.history import answers as healthy
from prefect import flow, get_run_logger

log = logging.getLogger("motionweb.app")


@flow(name="app-query", persist_result=False)
def app_query(kind: str, parameters: dict[str, Any], outcome: dict[str, Any]) -> dict[str, Any]:
    """The record of one query the service answered (``kind``: search, register, query, synthesize, blend): its
    parameters and outcome (generation, ε, matches, timings) in the run's log and result."""
    get_run_logger().info("%s %s -> %s", kind, parameters, outcome)
    return outcome


def free_port(host: str = "127.0.0.1") -> int:
    with socket.socket() as s:
        s.bind((host, 0))
        return s.getsockname()[1]


class PrefectServer:
    """The Prefect API the service records to: ``PREFECT_API_URL`` when set and answering, else
    one answering at 127.0.0.1:4200, else a ``prefect server start`` of our own on a free
    loopback port (stopped with the service; its log in ``log_path``)."""

    def __init__(self, log_path: Path | None = None):
        self.url: str | None = None
        self.proc: subprocess.Popen | None = None
        self.log_path = log_path
        self.ready = threading.Event()

    def start(self) -> None:
        """Find or start the server (returns at once; :attr:`ready` is set when it answers)."""
        for url in (os.environ.get("PREFECT_API_URL"), "http://127.0.0.1:4200/api"):
            if url and healthy(url):
                self.url = url
                self.ready.set()
                return
        port = free_port()
        self.url = f"http://127.0.0.1:{port}/api"
        out = open(self.log_path, "ab") if self.log_path else subprocess.DEVNULL  # noqa: SIM115
        env = {**os.environ, "PREFECT_SERVER_ANALYTICS_ENABLED": "false", "PREFECT_UI_ENABLED": "true"}
        env.pop("PREFECT_API_URL", None)
        self.proc = subprocess.Popen([sys.executable, "-m", "prefect", "server", "start", "--host", "127.0.0.1",
                                      "--port", str(port)], stdout=out, stderr=subprocess.STDOUT, env=env,
                                     start_new_session=True)
        threading.Thread(target=self._wait, name="prefect-server", daemon=True).start()

    def _wait(self, timeout: float = 300.0) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and self.proc.poll() is None:
            if healthy(self.url):
                self.ready.set()
                return
            time.sleep(0.5)
        log.warning("the Prefect server did not start (%s); queries are not recorded", self.log_path or "no log")

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(20)
            except subprocess.TimeoutExpired:
                self.proc.kill()


class Recorder:
    """Runs :func:`app_query` for every recorded query, in one background thread against
    ``server``; :meth:`record` never blocks."""

    def __init__(self, server: PrefectServer, size: int = 1000):
        self.server = server
        self.queue: queue.Queue = queue.Queue(size)
        self.recorded = self.dropped = self.failed = 0
        self._thread = threading.Thread(target=self._run, name="recorder", daemon=True)
        self._thread.start()

    def record(self, kind: str, parameters: dict[str, Any], outcome: dict[str, Any]) -> None:
        try:
            self.queue.put_nowait((kind, parameters, outcome))
        except queue.Full:
            self.dropped += 1

    def _run(self) -> None:
        self.server.ready.wait()
        from prefect.settings import PREFECT_API_URL, PREFECT_FLOWS_HEARTBEAT_FREQUENCY, temporary_settings

        with temporary_settings({PREFECT_API_URL: self.server.url, PREFECT_FLOWS_HEARTBEAT_FREQUENCY: None}):
            while True:
                item = self.queue.get()
                if item is None:
                    return
                try:
                    app_query(*item)
                    self.recorded += 1
                except Exception:  # a record lost must not stop the service
                    self.failed += 1
                    log.exception("could not record a query as a Prefect flow run")
                finally:
                    self.queue.task_done()

    def close(self, timeout: float = 5.0) -> None:
        try:
            self.queue.put_nowait(None)
        except queue.Full:
            pass
        self._thread.join(timeout)
