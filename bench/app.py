"""Benchmark: `motionweb app` on the ~37,000-frame benchmark corpus — latency, load and faults.

Printed, in one run (targets from the issue):
  * today's cold CLI search (`motionweb search`, no service: Prefect's temporary server, imports,
    reading the webs) — the baseline;
  * the same search from the CLI with the service up (forwarded), ≤ 1 s, and whether every file it
    writes equals the cold run's byte for byte; split into importing the CLI and the service's
    answer to the forwarded request (search + drawing graph.png + the zip);
  * searches through the JSON API, warm (webs in memory), median and p90 over random 1.5 s
    queries of the webs' working rate and over one repeated query, ≤ 100 ms median;
  * load: 16 concurrent clients × 50 mixed requests (catalog, clip pose, search, registration,
    a registered match's pose, a BVH download): failures (target 0), p50 / p99 per kind;
  * faults: 20 clients that send a search and hang up at once (then the service's thread count
    and a search's latency again); an index run that commits a new generation while requests
    flow (none fails, the service switches); an index run SIGKILLed mid-way (none fails, the
    generation stays).

  * retime sessions (MPS06, flows/app/sessions.py; ``--sessions-only`` runs only these, on a small
    store of CMU subject 16 trials cut to 400 frames at 120 Hz): `motionweb retime` from the CLI
    (the baseline: one cold try), then through the warm service a timing edit (duration or a
    keytime) on a prepared clip, p50 ≤ 150 ms; a physics change (gravity or a limb's mass: a new
    session prepared, and its first edit) ≤ 1.5 s; preparing a new clip ≤ 2 s; each plan's bytes
    and the session worker's memory per prepared clip.

The corpus and its index (by category, 30 Hz) come from bench/corpus.py and are kept in --keep
(the layout bench/search.py uses: corpus/, store-category-30/), reused when present. The fault
runs index a copy of the corpus's demo categories only (a few seconds per run).

    .venv/bin/python -m bench.app [--keep DIR] [--clients 16] [--requests 50] [--faults-only | --cli-only |
                                  --sessions-only]
"""

from __future__ import annotations

import argparse
import http.client
import json
import os
import random
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
os.environ.setdefault("PREFECT_LOGGING_LEVEL", "WARNING")
os.environ.setdefault("PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS", "300")
os.environ.setdefault("DASK_LOGGING__DISTRIBUTED", "error")

import numpy as np
import psutil
import yaml
from motionweb.store.datasets import mocap_root
from motionweb.store.generations import load_generation
from motionweb.store.zarr_store import MotionStore

from bench.corpus import build_corpus, run_index

QUERY_S = 1.5
RATE = 30.0


def motionweb(*args: str, env: dict | None = None, **kw) -> subprocess.CompletedProcess:
    exe = Path(sys.executable).parent / "motionweb"
    return subprocess.run([str(exe), *args], capture_output=True, text=True, env=env, **kw)


class Api:
    """A keep-alive HTTP client of the service (one per thread)."""

    def __init__(self, url: str):
        host, port = url.removeprefix("http://").rsplit(":", 1)
        self.conn = http.client.HTTPConnection(host, int(port), timeout=120)
        self.last = 0.0

    def call(self, method: str, path: str, body: dict | None = None) -> tuple[int, bytes]:
        data = None if body is None else json.dumps(body).encode()
        if time.monotonic() - self.last > 4.0:  # uvicorn closes idle keep-alive connections after 5 s
            self.conn.close()
        self.conn.request(method, path, body=data, headers={"Content-Type": "application/json"} if data else {})
        r = self.conn.getresponse()
        out = r.status, r.read()
        self.last = time.monotonic()
        return out

    def json(self, method: str, path: str, body: dict | None = None) -> dict:
        status, data = self.call(method, path, body)
        if status != 200:
            raise RuntimeError(f"{method} {path}: {status} {data[:200]!r}")
        return json.loads(data)


def start_service(cfg_path: Path, env: dict) -> tuple[subprocess.Popen, str]:
    exe = Path(sys.executable).parent / "motionweb"
    proc = subprocess.Popen([str(exe), "app", str(cfg_path), "--port", "0"], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, env=env, start_new_session=True)
    line = proc.stdout.readline()
    if "motionweb app:" not in line:
        raise RuntimeError(f"the service did not start: {line}{proc.stdout.read()}")
    url = line.split("motionweb app:")[1].split()[0].rstrip("/")
    threading.Thread(target=proc.stdout.read, daemon=True).start()  # keep its pipe drained
    return proc, url


def wait_warm(api: Api, timeout: float = 1200) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        s = api.json("GET", "/api/status")
        if s.get("warm") and s.get("worker", {}).get("standby", True):  # and the standby search worker warm
            return s
        time.sleep(0.5)
    raise RuntimeError("the service did not warm up in time")


def random_queries(gen, n: int, rng: np.random.Generator) -> list[dict]:
    clips = [c for c in gen.clips if c["duration"] > QUERY_S + 0.2]
    out = []
    for k in rng.choice(len(clips), n):
        c = clips[k]
        s = float(rng.uniform(0, c["duration"] - QUERY_S - 0.1))
        out.append({"clip": c["path"], "start": round(s, 3), "end": round(s + QUERY_S, 3), "quantile": 0.05,
                    "tiers": 3})
    return out


def pct(xs: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(xs) * 1000, q)) if xs else float("nan")


def load_test(url: str, queries: list[dict], clients: int, per_client: int) -> dict:
    """``clients`` threads × ``per_client`` mixed requests; per kind latencies, failures."""
    times: dict[str, list[float]] = {}
    failures: list[str] = []
    lock = threading.Lock()
    clip_ids = [c["id"] for c in Api(url).json("GET", "/api/catalog?limit=5000")["clips"]]

    def client(k: int) -> None:
        rnd = random.Random(k)
        api = Api(url)
        result = None
        for i in range(per_client):
            kind = ["catalog", "pose", "search", "search", "registration", "match pose", "bvh"][i % 7]
            if kind in ("registration", "match pose", "bvh") and result is None:
                kind = "search"
            t = time.perf_counter()
            try:
                if kind == "catalog":
                    status, _ = api.call("GET", f"/api/catalog?name={rnd.choice('abcdeiklmnoprstuvw')}")
                elif kind == "pose":
                    status, _ = api.call("GET", f"/api/clips/{rnd.choice(clip_ids)}/pose?rate=30")
                elif kind == "search":
                    status, data = api.call("POST", "/api/search", rnd.choice(queries))
                    if status == 200:
                        result = json.loads(data)
                elif kind == "registration":
                    status, _ = api.call("GET", f"/api/results/{result['result']}/registration")
                elif kind == "match pose":
                    rank = rnd.randrange(1 + len(result["matches"]))
                    status, _ = api.call("GET", f"/api/results/{result['result']}/nodes/{rank}/pose?registered=true")
                else:
                    rank = rnd.randrange(1 + len(result["matches"]))
                    status, _ = api.call("GET", f"/api/results/{result['result']}/nodes/{rank}/bvh")
                ok = status == 200
            except Exception as exc:  # a failure to count, not to stop the test
                ok, status = False, repr(exc)
                api = Api(url)
            dt = time.perf_counter() - t
            with lock:
                times.setdefault(kind, []).append(dt)
                if not ok:
                    failures.append(f"{kind}: {status}")

    t0 = time.perf_counter()
    threads = [threading.Thread(target=client, args=(k,)) for k in range(clients)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return {"times": times, "failures": failures, "wall": time.perf_counter() - t0}


def cli_query(store_path: Path, gen, queries: list[dict]) -> dict:
    """The first of ``queries`` with a match in another clip (the default ε rule needs one)."""
    from motionweb.flows.query import indexed_config
    from motionweb.store.webs import StoreWebs
    from motionweb.tasks.matchgraph import Segment
    from motionweb.tasks.ranking import nearest_costs
    from motionweb.tasks.search import MatchSearch, SearchParams

    store = MotionStore(str(store_path), read_only=True)
    matchweb = indexed_config(gen).matchweb
    for q in queries:
        webs = StoreWebs.for_query(store, q["clip"], generation=gen)
        seg = Segment(q["clip"], round(q["start"] * RATE), round(q["end"] * RATE))
        if nearest_costs(MatchSearch(webs, SearchParams(), matchweb), seg):
            return q
    raise RuntimeError("no query matches another clip")


def files_of(d: Path) -> dict[str, bytes]:
    return {p.relative_to(d).as_posix(): p.read_bytes() for p in sorted(d.rglob("*")) if p.is_file()}


def cli_with_service(cli_args: list[str], work: Path, env: dict, cold: float, api: Api) -> None:
    """Five forwarded CLI searches (the cold run's query and --out): wall time, files equal to the
    cold run's byte for byte, and the parts: importing the CLI, the service's answer."""
    fwd, same = [], []
    cold_files = files_of(work / "cold")
    for _ in range(5):
        shutil.rmtree(work / "cli", ignore_errors=True)
        t = time.perf_counter()
        r = motionweb(*cli_args, env=env)
        fwd.append(time.perf_counter() - t)
        assert r.returncode == 0 and "by the service" in r.stdout, r.stdout + r.stderr
        same.append(files_of(work / "cli") == cold_files)
    n = len(json.loads((work / "cold" / "matches.json").read_text())["matches"])
    print(f"CLI search with the service up: median {np.median(fwd):.2f} s, best {min(fwd):.2f} s of 5   "
          f"target: <= 1 s; cold was {cold:.1f} s")
    print(f"  {len(cold_files)} files, {n} matches; every file byte-identical to the cold run's: {all(same)}")
    imp = subprocess.run([sys.executable, "-X", "importtime", "-c", "import motionweb.flows.commands.cli"],
                         capture_output=True, text=True)
    total_us = max(int(line.split("|")[1]) for line in imp.stderr.splitlines() if line.startswith("import time:")
                   and line.split("|")[1].strip().isdigit())
    opts = dict(zip(cli_args[2::2], cli_args[3::2], strict=False))
    body = {"clip": opts["--clip"], "start": float(opts["--start"]), "end": float(opts["--end"]),
            "tiers": int(opts["--tiers"]), "out": opts["--out"]}
    answer = []
    for _ in range(5):
        t = time.perf_counter()
        status, _ = api.call("POST", "/api/query", body)
        answer.append(time.perf_counter() - t)
    print(f"  of which importing the CLI: {total_us / 1e6:.2f} s; the service's answer (POST /api/query: search, "
          f"graph.png, zip) median {pct(answer, 50):.0f} ms (status {status})")


def hang_ups(url: str, body: dict, n: int) -> None:
    """``n`` clients that send a search and close the socket without reading the answer."""
    host, port = url.removeprefix("http://").rsplit(":", 1)
    data = json.dumps(body).encode()
    for _ in range(n):
        s = socket.create_connection((host, int(port)))
        s.sendall(b"POST /api/search HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
                  + f"Content-Length: {len(data)}\r\n\r\n".encode() + data)
        s.close()


def hammer(url: str, body: dict, stop: threading.Event, out: dict) -> None:
    """Searches back to back until ``stop``; counts answers, failures and generations seen."""
    api = Api(url)
    while not stop.is_set():
        try:
            status, data = api.call("POST", "/api/search", body)
            if status == 200:
                out["ok"] += 1
                out["generations"].add(json.loads(data)["generation"])
            else:
                out["failed"].append(status)
        except Exception as exc:
            out["failed"].append(repr(exc))
            api = Api(url)


def faults(work: Path, env: dict) -> None:
    """A small store (the demo categories of the corpus) served while index runs commit / die."""
    small = work / "faults"
    shutil.rmtree(small, ignore_errors=True)
    corpus = small / "corpus"
    for cat in ("walk", "run", "kick"):
        shutil.copytree(work / "corpus" / cat, corpus / cat)
    cfg_path = small / "config.yaml"
    cfg_path.write_text(yaml.safe_dump({"corpus": {"path": "corpus", "length_unit": "m"},
                                        "features": {"rates": [10.0, 20.0, 30.0]}, "store": {"path": "store"},
                                        "dask": {"processes": False}}))
    r = motionweb("index", str(cfg_path), "--no-progress", env=env)
    if r.returncode:
        print(f"  faults: index failed: {r.stderr[-300:]}")
        return
    proc, url = start_service(cfg_path, env)
    try:
        api = Api(url)
        first = api.json("GET", "/api/status")["generation"]
        clip = sorted(p.relative_to(corpus).as_posix() for p in (corpus / "walk").glob("*.bvh"))[0]
        body = {"clip": clip, "start": 0.5, "end": 2.0, "quantile": 0.5}
        api.json("POST", "/api/search", body)
        # hang-ups
        me = psutil.Process(proc.pid)
        threads0 = me.num_threads()
        t = time.perf_counter()
        api.json("POST", "/api/search", body)
        before = time.perf_counter() - t
        hang_ups(url, body, 20)
        time.sleep(2.0)
        t = time.perf_counter()
        api.json("POST", "/api/search", body)
        after = time.perf_counter() - t
        print(f"  20 clients hung up mid-search: service threads {threads0} -> {me.num_threads()}, "
              f"a search {before * 1000:.0f} ms before, {after * 1000:.0f} ms after; status "
              f"{Api(url).call('GET', '/api/status')[0]}")
        # a killed index run
        out = {"ok": 0, "failed": [], "generations": set()}
        stop = threading.Event()
        th = threading.Thread(target=hammer, args=(url, body, stop, out))
        th.start()
        victim = sorted((corpus / "run").glob("*.bvh"))[0]
        victim.write_text(victim.read_text() + "\n")
        exe = Path(sys.executable).parent / "motionweb"
        idx = subprocess.Popen([str(exe), "index", str(cfg_path), "--no-progress"], stdout=subprocess.DEVNULL,
                               stderr=subprocess.DEVNULL, env=env, start_new_session=True)
        objects = small / "store" / "webs"
        seen = {p for p in objects.rglob("*") if p.is_file()}
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline and idx.poll() is None and not ({p for p in objects.rglob("*")
                                                                             if p.is_file()} - seen):
            time.sleep(0.05)
        os.killpg(idx.pid, signal.SIGKILL)
        idx.wait()
        time.sleep(1.0)
        kept = api.json("GET", "/api/status")["generation"]
        print(f"  index run SIGKILLed mid-way: {out['ok']} searches answered meanwhile, {len(out['failed'])} failed; "
              f"generation {'unchanged' if kept == first else 'CHANGED'}")
        # a run that commits
        n0 = out["ok"]
        r = motionweb("index", str(cfg_path), "--no-progress", env=env)
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and api.json("GET", "/api/status")["generation"] == first:
            time.sleep(0.2)
        time.sleep(1.0)
        stop.set()
        th.join()
        now = api.json("GET", "/api/status")["generation"]
        print(f"  index run committed while serving (exit {r.returncode}): {out['ok'] - n0} searches answered "
              f"meanwhile, {len(out['failed'])} failed in all; switched to the new generation: {now != first}; "
              f"generations seen by searches: {len(out['generations'])}")
    finally:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(30)


SESSION_FRAMES = 400
SESSION_CLIPS = ("16_16", "16_15", "16_11", "16_12", "16_35", "16_08")


def session_store(work: Path) -> Path:
    """A small indexed store of CMU subject 16 trials cut to their first :data:`SESSION_FRAMES`
    frames (BVH in the ASF's unit; the config says ``scale_to_m``), and its config."""
    from motionweb.flows.config import Config
    from motionweb.flows.index import index_library
    from motionweb.store.bvh import write_bvh
    from motionweb.store.formats import read_motion
    from motionweb.store.kinematics import sample_motion

    corpus, store, cfg_path = work / "retime-corpus", work / "retime-store", work / "retime.yaml"
    scale = 0.0254 / 0.45  # the CMU ASF's unit (README, CMU formats)
    cfg = {"corpus": {"path": str(corpus), "scale_to_m": scale}, "features": {"rates": [10.0, 30.0]},
           "store": {"path": str(store)}, "dask": {"processes": False}, "output": str(work / "retime-out")}
    if load_generation(MotionStore(str(store))) is None:
        shutil.rmtree(corpus, ignore_errors=True)
        for name in SESSION_CLIPS:
            m = read_motion(mocap_root() / "cmu" / "asf_amc" / "16" / f"{name}.amc", scale_to_m=scale)
            if m.n_frames < SESSION_FRAMES:
                continue
            cut = sample_motion(m, np.arange(SESSION_FRAMES, dtype=float))
            (corpus / "cmu16").mkdir(parents=True, exist_ok=True)
            write_bvh(cut, corpus / "cmu16" / f"{name}.bvh")
        index_library(Config.model_validate(cfg))
    cfg_path.write_text(yaml.safe_dump(cfg))
    return cfg_path


def sessions(work: Path, env: dict, edits: int = 30) -> None:
    """The retime sessions' figures (see the module docstring), the CLI's beside them."""
    cfg_path = session_store(work)
    gen = load_generation(MotionStore(str(work / "retime-store"), read_only=True))
    clips = sorted(c["path"] for c in gen.clips)
    first = clips[0]
    src = work / "retime-corpus" / first
    print(f"retime sessions: {len(clips)} clips of {SESSION_FRAMES} frames at 120 Hz (CMU subject 16); "
          f"load average {os.getloadavg()[0]:.1f}")
    dur = SESSION_FRAMES / 120.0
    t = time.perf_counter()
    r = motionweb("retime", str(src), "--duration", f"{0.8 * dur:.3f}", "--out", str(work / "retime-cli.bvh"),
                  "--config", str(cfg_path), env=env)
    cli = time.perf_counter() - t
    print(f"  CLI `motionweb retime {first} --duration {0.8 * dur:.3f}` (cold, today): {cli:.1f} s (exit {r.returncode})")
    proc, url = start_service(cfg_path, env)
    try:
        api = Api(url)
        wait_warm(api)
        t = time.perf_counter()
        s = api.json("POST", "/api/retime/sessions", {"clip": first})
        api.json("POST", f"/api/retime/sessions/{s['session']}/edit", {"duration": 0.8 * dur})
        print(f"  warm-up (the session worker's start, imports, compiled kernels): {time.perf_counter() - t:.1f} s")
        rss0 = psutil.Process(api.json("GET", "/api/retime/status")["pid"]).memory_info().rss
        rng = random.Random(5)
        times, server, cpu = [], [], []
        for k in range(edits):
            body = ({"duration": round(dur * rng.uniform(0.75, 1.3), 3)} if k % 2 == 0 else
                    {"duration": round(dur, 3), "keytimes": [[1.5, round(rng.uniform(1.1, 1.9), 3)]]})
            t = time.perf_counter()
            e = api.json("POST", f"/api/retime/sessions/{s['session']}/edit", body)
            times.append(time.perf_counter() - t)
            server.append(e["edit_s"])
            cpu.append(e["cpu_s"])
        print(f"  timing edit on a prepared clip (duration or a keytime), {edits} edits through HTTP: p50 "
              f"{pct(times, 50):.0f} ms, p90 {pct(times, 90):.0f} ms (in the service p50 {pct(server, 50):.0f} ms; "
              f"CPU of the worker p50 {pct(cpu, 50):.0f} ms)   target: p50 <= 150 ms")
        phys, pcpu = [], []
        held = api.json("GET", "/api/retime/status")["plan_bytes"]
        bodies = [{"gravity": g} for g in ([1.0, -9.81, 0.0], [0.0, -4.9, 0.0], [0.0, -14.0, 0.0])] + \
                 [{"mass": {joint: 3.0}} for joint in ("lfemur", "rtibia")]
        for b in bodies:
            t = time.perf_counter()
            p = api.json("POST", "/api/retime/sessions", {"clip": first, **b})
            e = api.json("POST", f"/api/retime/sessions/{p['session']}/edit", {"duration": 0.8 * dur})
            phys.append(time.perf_counter() - t)
            pcpu.append(p["cpu_s"] + e["cpu_s"])
        grown = api.json("GET", "/api/retime/status")["plan_bytes"] - held
        print(f"  physics change (3 gravities, 2 limb masses: a new session prepared, and its first edit): "
              f"p50 {pct(phys, 50) / 1000:.2f} s, max {max(phys):.2f} s (CPU of the worker p50 "
              f"{pct(pcpu, 50) / 1000:.2f} s)   target: <= 1.5 s; each physics of a kept clip adds "
              f"{grown / len(bodies) / 1e6:.1f} MB to the cache")
        new, sizes, ncpu = [], [], []
        for clip in clips[1:]:
            t = time.perf_counter()
            p = api.json("POST", "/api/retime/sessions", {"clip": clip})
            new.append(time.perf_counter() - t)
            sizes.append(p["plan_bytes"])
            ncpu.append(p["cpu_s"])
        st = api.json("GET", "/api/retime/status")
        rss1 = psutil.Process(st["pid"]).memory_info().rss
        n_new = len(clips) - 1
        print(f"  preparing a new {SESSION_FRAMES}-frame clip ({n_new} clips): p50 {pct(new, 50) / 1000:.2f} s, "
              f"max {max(new):.2f} s (CPU of the worker p50 {pct(ncpu, 50) / 1000:.2f} s)   target: <= 2 s")
        print(f"  memory: a new clip's plan holds {np.median(sizes) / 1e6:.1f} MB of arrays (median); the session worker's RSS "
              f"grew {(rss1 - rss0) / 1e6 / max(n_new, 1):.1f} MB per new clip ({rss1 / 1e6:.0f} MB in all, "
              f"{st['plans']} plans kept, {st['plan_bytes'] / 1e6:.0f} MB, {st['evicted']} evicted)")
        # a warp session (HDP07) at a size of Table 1: n = r = 400 (self reference), m = 230, s = 8
        t = time.perf_counter()
        w = api.json("POST", "/api/warp/sessions", {"clip": first})
        m_s = 229 / 120.0
        e = api.json("POST", f"/api/warp/sessions/{w['session']}/edit", {"duration": m_s})
        first_warp = time.perf_counter() - t
        wt, wcpu = [], []
        for k in range(edits):
            body = {"duration": round(m_s * rng.uniform(0.9, 1.1), 3),
                    "keytimes": [] if k % 2 == 0 else [[1.6, round(rng.uniform(0.7, 1.1), 3)]]}
            t = time.perf_counter()
            e = api.json("POST", f"/api/warp/sessions/{w['session']}/edit", body)
            wt.append(time.perf_counter() - t)
            wcpu.append(e["cpu_s"])
        print(f"  warp session (HDP07, n = r = {SESSION_FRAMES}, m ~ {round(m_s * 120) + 1}, s = 8, full search): "
              f"open + first warp (the local scores) {first_warp:.2f} s; {edits} edits (duration or a keytime) "
              f"through HTTP p50 {pct(wt, 50):.0f} ms, p90 {pct(wt, 90):.0f} ms (CPU of the worker p50 "
              f"{pct(wcpu, 50):.0f} ms)   target: <= 300 ms per edit")
    finally:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(60)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--keep", default=None, help="work folder (corpus/, store-category-30/), reused when present")
    ap.add_argument("--frames", type=int, default=37000)
    ap.add_argument("--clients", type=int, default=16)
    ap.add_argument("--requests", type=int, default=50)
    ap.add_argument("--queries", type=int, default=40)
    ap.add_argument("--faults-only", action="store_true", help="only the fault runs (needs --keep with a corpus)")
    ap.add_argument("--cli-only", action="store_true", help="only the CLI timings (cold, then with the service)")
    ap.add_argument("--sessions-only", action="store_true", help="only the retime sessions' figures")
    args = ap.parse_args()
    if args.sessions_only:
        if not mocap_root().is_dir():
            print(f"real motion capture not found at {mocap_root()}: the sessions need CMU subject 16")
            return
        work = Path(args.keep or tempfile.mkdtemp(prefix="motionweb-bench-app-"))
        work.mkdir(parents=True, exist_ok=True)
        sessions(work, {**os.environ, "MOTIONWEB_APP_DIR": str(work / "discovery")})
        print(f"load average at the end {os.getloadavg()[0]:.1f}")
        return
    if args.faults_only:
        work = Path(args.keep)
        print("faults (a store of the corpus's walk, run and kick clips):")
        faults(work, {**os.environ, "MOTIONWEB_APP_DIR": str(work / "discovery")})
        return
    if not mocap_root().is_dir():
        print(f"real motion capture not found at {mocap_root()}: the bench corpus needs it (set MOTIONWEB_MOCAP)")
        return
    work = Path(args.keep or tempfile.mkdtemp(prefix="motionweb-bench-app-"))
    work.mkdir(parents=True, exist_ok=True)
    if not (work / "corpus").is_dir():
        info = build_corpus(work / "corpus", args.frames)
        print(f"corpus: {info['clips']} clips, {info['frames60']} frames at 60 Hz")
    store_path = work / f"store-category-{RATE:g}"
    if load_generation(MotionStore(str(store_path))) is None:
        from prefect.settings import PREFECT_FLOWS_HEARTBEAT_FREQUENCY, temporary_settings

        with temporary_settings({PREFECT_FLOWS_HEARTBEAT_FREQUENCY: None}):
            s = run_index(work / "corpus", store_path, RATE, "category", 2)
        print(f"index: {s['pairs']} webs in {s['wall_s']:.1f} s")
    gen = load_generation(MotionStore(str(store_path), read_only=True))
    frames = sum(c["frames"] for c in gen.clips)
    cfg_path = work / "app.yaml"
    cfg_path.write_text(yaml.safe_dump({"corpus": {"path": str(work / "corpus"), "length_unit": "m"},
                                        "store": {"path": str(store_path)}, "output": str(work / "out")}))
    load = os.getloadavg()
    print(f"{len(gen.clips)} clips, {frames} frames, {len(gen.webs)} webs at {RATE:g} Hz (by category); "
          f"{os.cpu_count()} cores, load average {load[0]:.1f} at the start (shared machine: timings are noisy)")
    rng = np.random.default_rng(3)
    queries = random_queries(gen, args.queries, rng)
    q0 = queries[0]
    cq = cli_query(store_path, gen, queries)
    # the CLI's query: the default ε rule (a multiple of its nearest match), so it finds matches
    cli_args = ["search", str(cfg_path), "--clip", cq["clip"], "--start", str(cq["start"]), "--end", str(cq["end"]),
                "--tiers", "3", "--out", str(work / "cli")]
    env = {**os.environ, "MOTIONWEB_APP_DIR": str(work / "discovery")}
    shutil.rmtree(work / "discovery", ignore_errors=True)

    shutil.rmtree(work / "cli", ignore_errors=True)
    t = time.perf_counter()
    r = motionweb(*cli_args, env=env)
    cold = time.perf_counter() - t
    if r.returncode != 0:
        raise RuntimeError(f"the cold CLI search failed: {r.stderr[-500:]}")
    shutil.rmtree(work / "cold", ignore_errors=True)
    (work / "cli").rename(work / "cold")
    print(f"\ncold CLI search, no service (today): {cold:.1f} s (exit {r.returncode}; "
          f"{r.stdout.strip().splitlines()[-1] if r.stdout.strip() else r.stderr[-200:]})")

    t = time.perf_counter()
    proc, url = start_service(cfg_path, env)
    try:
        api = Api(url)
        s = wait_warm(api)
        print(f"service {url}: listening, then all {s['webs']} webs read and packed in {time.perf_counter() - t:.1f} s")
        for q in queries:  # each clip's first search (its ε quantile) once
            api.json("POST", "/api/search", q)
        same, rand = [], []
        for _ in range(30):
            t = time.perf_counter()
            api.json("POST", "/api/search", q0)
            same.append(time.perf_counter() - t)
        for q in queries:
            t = time.perf_counter()
            api.json("POST", "/api/search", q)
            rand.append(time.perf_counter() - t)
        print(f"API search, warm, through HTTP: one query repeated x30 median {pct(same, 50):.1f} ms, "
              f"p90 {pct(same, 90):.1f} ms; {len(queries)} random {QUERY_S:g} s queries (3 tiers) median "
              f"{pct(rand, 50):.1f} ms, p90 {pct(rand, 90):.1f} ms   target: median <= 100 ms")
        cli_with_service(cli_args, work, env, cold, api)
        if args.cli_only:
            return

        res = load_test(url, queries, args.clients, args.requests)
        allt = [x for v in res["times"].values() for x in v]
        print(f"\nload: {args.clients} clients x {args.requests} mixed requests = {len(allt)} in {res['wall']:.1f} s, "
              f"{len(res['failures'])} failures   target: 0")
        print(f"  {'kind':14s} {'n':>4s} {'p50 ms':>8s} {'p99 ms':>8s}")
        for kind, v in sorted(res["times"].items()):
            print(f"  {kind:14s} {len(v):4d} {pct(v, 50):8.1f} {pct(v, 99):8.1f}")
        print(f"  {'all':14s} {len(allt):4d} {pct(allt, 50):8.1f} {pct(allt, 99):8.1f}")
        if res["failures"]:
            print(f"  failures: {res['failures'][:5]}")
    finally:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(60)
    print()
    sessions(work, env)
    print("\nfaults (a store of the corpus's walk, run and kick clips):")
    faults(work, env)
    print(f"load average at the end {os.getloadavg()[0]:.1f}")
    if not args.keep:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
