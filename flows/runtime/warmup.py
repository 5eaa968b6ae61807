"""Start what a command will need while it does other work (issue 23): its compiled kernels, in
parallel processes, and Prefect's local API server.

``motionweb demo`` on a fresh install spends most of its time compiling the index and search
kernels (``motionweb.tasks.warm``): on the one thread that first calls each kernel, one core busy,
while the CLI also waits seconds for Prefect's local API server and the Dask cluster. :func:`start`
launches one process per share of the kernels (:func:`motionweb.tasks.warm.shares`, default one per
core, at most 2) that compile them into numba's on-disk cache; the command writes its corpus and
starts its services meanwhile, and calls :meth:`Warmup.wait` before the first kernel call, which
then loads the cached code. A warm-up that fails (a kernel that cannot compile here) costs nothing
but time: the run compiles on first use as without it, and the failure is logged, not raised.

A flow run with no Prefect server configured starts Prefect's local ("ephemeral") API server
first, a subprocess that takes seconds to answer (more on a fresh machine, whose database is
created then). :func:`start_prefect` starts it in a background thread, the same instance the flow
run then finds (``SubprocessASGIServer`` is one per process), so that this wait overlaps the
warm-up and the command's own work.

Second and later runs find the cache and the processes return at once (a cached kernel is loaded,
~10 ms). ``MOTIONWEB_WARMUP=0`` turns the warm-up off (the previous behaviour, for comparison:
``bench/demo.py``). The processes are children of the CLI: its reaper (flows/runtime/reaper.py) ends them
with it.
"""

from __future__ import annotations

import logging
import os
import subprocess
import sys
import threading
import time

log = logging.getLogger(__name__)


class Warmup:
    """The running warm-up processes of one command (none: a no-op)."""

    def __init__(self, procs: list[subprocess.Popen]):
        self.procs = procs
        self.t0 = time.perf_counter()
        self.seconds: float | None = None

    def wait(self, timeout: float = 600.0) -> float:
        """Wait for every share (once; later calls return at once); seconds since the start. A share
        that failed or ran out of time is logged (its last error line) and otherwise ignored."""
        if self.seconds is None:
            for p in self.procs:
                try:
                    _, err = p.communicate(timeout=max(1.0, timeout - (time.perf_counter() - self.t0)))
                except subprocess.TimeoutExpired:
                    p.kill()
                    _, err = p.communicate()
                if p.returncode != 0:
                    last = (err.decode(errors="replace").strip().splitlines() or [""])[-1]
                    log.warning("kernel warm-up ended with exit %s (%s): kernels compile on first use",
                                p.returncode, last)
            self.seconds = time.perf_counter() - self.t0
        return self.seconds


class PrefectStart:
    """Prefect's local API server starting in a background thread (or nothing to wait for)."""

    def __init__(self, thread: threading.Thread | None):
        self.thread = thread
        self.error: BaseException | None = None

    def wait(self) -> None:
        """Wait for the server to answer; a failure is logged, and the flow run then reports its own."""
        if self.thread is not None:
            self.thread.join()
            self.thread = None
            if self.error is not None:
                log.warning("Prefect's local server did not start ahead: %s", self.error)


def start_prefect() -> PrefectStart:
    """Start Prefect's local API server in a background thread when a flow run would start one: no
    ``PREFECT_API_URL`` configured, warm-ups enabled. Call :meth:`PrefectStart.wait` before the flow."""
    from motionweb.flows.runtime.history import configured_api_url

    if not enabled() or configured_api_url():
        return PrefectStart(None)
    started = PrefectStart(None)

    def run() -> None:
        try:
            from prefect.server.api.server import SubprocessASGIServer
            from prefect.settings import PREFECT_SERVER_EPHEMERAL_ENABLED

            if PREFECT_SERVER_EPHEMERAL_ENABLED.value():
                SubprocessASGIServer().start()
        except Exception as exc:  # noqa: BLE001 - reported by wait(); the flow run then tries itself
            started.error = exc

    started.thread = threading.Thread(target=run, name="prefect-start", daemon=True)
    started.thread.start()
    return started


def enabled() -> bool:
    """Whether warm-ups run (``MOTIONWEB_WARMUP=0`` turns them off)."""
    return os.environ.get("MOTIONWEB_WARMUP", "1") != "0"


def start(groups: list[str], processes: int | None = None, nice: int = 0) -> Warmup:
    """Start compiling ``groups``' kernels (``motionweb.tasks.warm.GROUPS``) in ``processes`` child
    processes (default: one per core, at most 2) at niceness ``nice`` (a positive one: they take
    the cores only while nothing else wants them); none when disabled (see :func:`enabled`)."""
    from motionweb.tasks.warm import kernels, shares

    if not enabled():
        return Warmup([])
    kernels(groups)  # an unknown group fails here, in the caller
    n = processes or max(1, min(2, os.cpu_count() or 1))
    procs = [subprocess.Popen([sys.executable, "-m", "motionweb.flows.runtime.warmup", str(i), str(n), str(nice),
                               *groups], stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
             for i in range(len(shares(groups, n)))]
    return Warmup(procs)


def ahead_of_index(local_cluster: bool) -> list[Warmup | PrefectStart]:
    """What ``motionweb index`` starts before its flow: Prefect's local server when the flow run
    needs one and, only then, the index kernels' warm-up beside it (on a local cluster), which
    that wait hides. With a server configured the flow starts at once and the kernels compile on
    first use (a cached warm-up still costs ~1.5 s of imports, more than it would save there)."""
    prefect = start_prefect()
    if prefect.thread is None or not local_cluster:
        return [prefect]
    return [start(["read", "index"]), prefect]


def main(argv: list[str]) -> int:
    """``python -m motionweb.flows.runtime.warmup SHARE N NICE GROUP...``: compile share SHARE of N
    at niceness NICE."""
    from motionweb.tasks.warm import compile_share, shares

    share, n, nice, groups = int(argv[0]), int(argv[1]), int(argv[2]), argv[3:]
    if nice > 0:
        os.nice(nice)
    compile_share(shares(groups, n)[share])
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
