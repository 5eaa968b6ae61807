"""`motionweb app` survives a crash in a search (issue 22, part 3): the search worker is made to
SIGSEGV / abort by the test hook (``MOTIONWEB_TEST_CRASH_CLIP``) while other clients search;
the crashing request gets a JSON error naming the query, the others see no failure, the service
answers again within 2 s, and no worker process is left after shutdown."""

from __future__ import annotations

import http.client
import json
import os
import threading
import time

import psutil
import pytest
from motionweb.flows.app.worker import CRASH_ENV

#: a search of run_02 makes the worker SIGSEGV, of run_01 abort (SIGABRT); registering a result of
#: walk_01 makes it SIGSEGV
CRASHES = "run_02,run_01:abort,walk_01:register"
NORMAL = [{"clip": "walk_00", "start": 1.0, "end": 2.5, "quantile": 0.8},
          {"clip": "walk_01", "start": 0.5, "end": 2.0, "quantile": 0.5, "tiers": 2},
          {"clip": "run_00", "start": 0.5, "end": 1.5, "threshold": 1.0},
          {"clip": "walk_02", "start": 0.5, "end": 2.0, "quantile": 0.8, "all_categories": True}]


def call(port: int, method: str, path: str, body: dict | None = None) -> tuple[int, dict]:
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=60)
    try:
        data = None if body is None else json.dumps(body).encode()
        conn.request(method, path, body=data, headers={"Content-Type": "application/json"} if data else {})
        r = conn.getresponse()
        raw = r.read()
        return r.status, json.loads(raw)
    finally:
        conn.close()


#: workers of other engines of this test session (e.g. test_app's), not the service's of this module
OTHERS: set[int] = set()
SEEN: set[int] = set()


def worker_pids() -> set[int]:
    """The search workers this module's service started, running or zombie."""
    def is_worker(p: psutil.Process) -> bool:
        try:
            return "motionweb.flows.app.worker" in " ".join(p.cmdline())
        except psutil.ZombieProcess:
            return p.pid in SEEN  # a zombie keeps no command line: one of ours if seen before
        except psutil.NoSuchProcess:
            return False

    found = {p.pid for p in psutil.Process().children(recursive=True) if p.pid not in OTHERS and is_worker(p)}
    SEEN.update(found)
    return found


@pytest.fixture(scope="module")
def crashy(app_store, tmp_path_factory):
    """A real service of ``app_store`` whose workers crash on run_02 (SIGSEGV) and run_01 (abort)."""
    from motionweb.flows.app.server import Service
    from motionweb.flows.config import load_config

    old = {k: os.environ.get(k) for k in (CRASH_ENV, "MOTIONWEB_APP_DIR")}
    OTHERS.update(worker_pids())
    os.environ[CRASH_ENV] = CRASHES
    os.environ["MOTIONWEB_APP_DIR"] = str(tmp_path_factory.mktemp("disc-crash"))
    svc = Service(load_config(app_store), port=0, record=False)
    t = svc.thread = threading.Thread(target=svc.run, daemon=True)
    t.start()
    try:
        wait_for(lambda: svc.server.started, 30, "the service to listen")
        wait_for(lambda: standby_ready(svc.port), 120, "the warm-up and the standby worker")
        yield svc
    finally:
        svc.stop()
        t.join(30)
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def wait_for(cond, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.05)


def standby_ready(port: int) -> bool:
    s = call(port, "GET", "/api/status")[1]
    return bool(s.get("warm") and s["worker"]["standby"] and s["worker"]["pid"])


def test_a_crashing_search_costs_only_itself(crashy) -> None:
    port = crashy.port
    for body in NORMAL:  # every scope and ε rule once, before the load
        status, res = call(port, "POST", "/api/search", body)
        assert status == 200, res
    stop = threading.Event()
    answered, failures = [0], []
    lock = threading.Lock()

    def load(k: int) -> None:
        i = k
        while not stop.is_set():
            body = NORMAL[i % len(NORMAL)]
            i += 1
            try:
                status, res = call(port, "POST", "/api/search", body) if i % 3 else call(port, "GET", "/api/catalog")
                ok = status == 200
            except Exception as exc:  # noqa: BLE001 - counted, not raised
                ok, res = False, repr(exc)
            with lock:
                answered[0] += ok
                if not ok:
                    failures.append(res)

    threads = [threading.Thread(target=load, args=(k,)) for k in range(3)]
    for t in threads:
        t.start()
    seen_workers: set[int] = set()
    recoveries = []
    try:
        time.sleep(1.0)
        for clip, signal_name in (("run_02", "SIGSEGV"), ("run_01", "SIGABRT"), ("run_02", "SIGSEGV")):
            wait_for(lambda: standby_ready(port), 60, "a standby worker")
            before = call(port, "GET", "/api/status")[1]["worker"]
            seen_workers |= worker_pids()
            body = {"clip": clip, "start": 0.5, "end": 1.5, "quantile": 0.5, "tiers": 2}
            status, res = call(port, "POST", "/api/search", body)
            crashed = time.monotonic()
            assert status == 500, res
            assert clip in res["error"] and signal_name in res["error"] and "Traceback" not in res["error"]
            assert res["query"]["clip"] == clip and res["query"]["start"] == 0.5 and res["query"]["end"] == 1.5
            status, again = call(port, "POST", "/api/search", NORMAL[0])
            recoveries.append(time.monotonic() - crashed)
            assert status == 200, again
            after = call(port, "GET", "/api/status")[1]["worker"]
            assert after["crashes"] == before["crashes"] + 1 and after["last_crash"] == signal_name
            assert after["pid"] != before["pid"]
            time.sleep(0.5)  # the load goes on meanwhile
    finally:
        stop.set()
        for t in threads:
            t.join(60)
    print(f"\n{answered[0]} requests answered under load, {len(failures)} failures; 3 crashes, answered again "
          f"after {', '.join(f'{r * 1000:.0f} ms' for r in recoveries)}")
    assert failures == [] and answered[0] > 20
    assert max(recoveries) < 2.0, recoveries
    # a bad request is still the client's error, not a crash
    status, res = call(port, "POST", "/api/search", {"clip": "walk_00", "start": 0, "end": 99, "quantile": 0.5})
    assert status == 400 and "outside clip" in res["error"]
    # the crashes left no worker behind: the dead ones are reaped, the live ones are the two in use
    seen_workers |= worker_pids()
    alive = worker_pids()
    assert len(alive) == 2 and len(seen_workers) >= 5
    assert set(crashy.engine.workers.pids()) == alive
    crashy.seen_workers = seen_workers


def test_a_crashing_registration_costs_only_itself(crashy) -> None:
    port = crashy.port
    wait_for(lambda: standby_ready(port), 60, "a standby worker")
    status, res = call(port, "POST", "/api/search", NORMAL[1])  # walk_01
    assert status == 200 and res["matches"], res
    status, err = call(port, "GET", f"/api/results/{res['result']}/registration")
    assert status == 500 and "registration" in err["error"] and "walk_01" in err["error"] and "SIGSEGV" in err["error"]
    assert err["query"]["clip"] == "walk_01" and "Traceback" not in err["error"]
    status, ok = call(port, "POST", "/api/search", NORMAL[0])
    assert status == 200
    status, reg = call(port, "GET", f"/api/results/{ok['result']}/registration")
    assert status == 200 and len(reg["nodes"]) == 1 + len(ok["matches"])
    crashy.seen_workers = getattr(crashy, "seen_workers", set()) | worker_pids()


def test_workers_give_freed_arrays_back_to_the_system(crashy) -> None:
    """Each search worker runs with glibc's mmap threshold fixed (flows/app/worker.Worker), so
    large arrays freed after a search do not stay in a fragmented heap."""
    from motionweb.flows.app.worker import MMAP_THRESHOLD

    wait_for(lambda: standby_ready(crashy.port), 60, "a standby worker")
    pids = worker_pids()
    assert len(pids) >= 2  # the primary and its standby
    for pid in pids:
        try:
            env = psutil.Process(pid).environ()
        except (psutil.NoSuchProcess, psutil.ZombieProcess):
            continue
        assert env.get("MALLOC_MMAP_THRESHOLD_") == str(MMAP_THRESHOLD)


def test_no_worker_is_left_after_shutdown(crashy) -> None:
    pids = getattr(crashy, "seen_workers", set()) | worker_pids()
    assert pids
    crashy.stop()
    crashy.thread.join(30)
    assert not crashy.thread.is_alive()
    assert worker_pids() == set()  # none running, none a zombie: each was waited for
    assert [pid for pid in pids if psutil.pid_exists(pid)] == []


def test_a_worker_raises_its_open_files_limit_for_its_mappings() -> None:
    """Each graph file a search worker keeps mapped holds a descriptor: the worker raises its soft
    limit on open files to the hard one (at most ``most``) before its file cache sizes its mappings
    by it; a limit it may not raise is kept."""
    import resource

    from motionweb.flows.app.worker import raise_open_files

    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    try:
        low = 64 if hard == resource.RLIM_INFINITY else min(64, int(hard))
        resource.setrlimit(resource.RLIMIT_NOFILE, (low, hard))
        want = 512 if hard == resource.RLIM_INFINITY else min(int(hard), 512)
        assert raise_open_files(most=512) == want == resource.getrlimit(resource.RLIMIT_NOFILE)[0]
        assert raise_open_files(most=32) == want  # never lowered
    finally:
        resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))
