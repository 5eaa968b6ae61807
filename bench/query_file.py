"""Benchmark: a query from a clip outside the index (``motionweb search --query-file``, issue 24).

Indexes the shared CMU ASF/AMC trials (manifest categories, symlinks with their ASF skeletons in a
work folder) but one held-out trial of about 10 s, then times a 1 s query from the held-out trial:
the CLI cold (a new process) and the work in-process (webs built on demand against every indexed
clip with its skeleton, then the tiered search), beside the index's own search of an indexed clip
of the same length (the floor: no webs to build). Target: the CLI answers in ≤ 2 s.

    .venv/bin/python -m bench.query_file [--mocap DIR] [--keep DIR] [--repeat 3]
"""

from __future__ import annotations

import argparse
import csv
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml


def mocap_dir(arg: str | None) -> Path:
    return Path(arg or os.environ.get("MOTIONWEB_MOCAP") or Path(__file__).resolve().parents[2] / "shared" / "data" / "mocap")


def build_corpus(cmu: Path, work: Path, held: str) -> tuple[Path, int]:
    """Symlinks of every ASF/AMC trial of the manifest but ``held`` (and each subject's ASF) and a
    manifest of their categories; the number of trials linked (fails loudly when none)."""
    rows = list(csv.DictReader((cmu / "manifest.csv").open()))
    corpus = work / "corpus"
    lines, n = ["path,category"], 0
    for r in rows:
        p = r["path"]
        if not p.startswith("asf_amc/") or p == held:
            continue
        src = cmu / p
        asf = src.with_name(src.stem.split("_")[0] + ".asf")
        if not (src.is_file() and asf.is_file()):
            continue
        dest = corpus / src.parent.name
        dest.mkdir(parents=True, exist_ok=True)
        for f in (src, asf):
            if not (dest / f.name).exists():
                os.symlink(f, dest / f.name)
        lines.append(f"{src.parent.name}/{src.name},{r['category']}")
        n += 1
    if n == 0:
        raise SystemExit(f"bench: no ASF/AMC trial with its skeleton under {cmu}")
    (work / "manifest.csv").write_text("\n".join(lines) + "\n")
    return corpus, n


def timed_cli(args: list[str], cwd: Path) -> float:
    t = time.perf_counter()
    r = subprocess.run([sys.executable, "-c", "from motionweb.flows.commands.cli import main; main()", *args], cwd=cwd,
                       capture_output=True, text=True, check=False)
    if r.returncode != 0:
        raise SystemExit(f"bench: motionweb {' '.join(args)} failed:\n{r.stdout}\n{r.stderr}")
    return time.perf_counter() - t


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mocap")
    ap.add_argument("--keep", type=Path)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--held", default="asf_amc/16/16_15.amc", help="the held-out trial (manifest path)")
    args = ap.parse_args()
    cmu = mocap_dir(args.mocap) / "cmu"
    work = (args.keep or Path(tempfile.mkdtemp(prefix="bench-qf-"))).resolve()
    work.mkdir(parents=True, exist_ok=True)
    _, n = build_corpus(cmu, work, args.held)
    cfg_path = work / "config.yaml"
    cfg_path.write_text(yaml.safe_dump({"corpus": {"path": "corpus", "manifest": "manifest.csv"},
                                        "store": {"path": "store"}, "output": "out"}))
    print(f"indexing {n} CMU trials (all but {args.held}) ...", flush=True)
    t = time.perf_counter()
    timed_cli(["index", str(cfg_path), "--no-progress"], work)
    print(f"  indexed in {time.perf_counter() - t:.1f} s", flush=True)

    from motionweb.flows.commands.requests import QueryRequest
    from motionweb.flows.config import load_config
    from motionweb.flows.query import committed_generation, plan_query, query
    from motionweb.store.formats import read_motion

    cfg = load_config(cfg_path)
    _, gen = committed_generation(cfg.store.path)
    if len(gen.clips) != n:
        raise SystemExit(f"bench: the index holds {len(gen.clips)} clips, not the {n} linked")
    held = cmu / args.held
    motion = read_motion(held)
    mid = motion.duration / 2
    a, b = mid - 0.5, mid + 0.5
    same = [c["path"] for c in gen.clips if c.get("skeleton") == motion.skeleton.signature()]
    indexed = max(gen.clips, key=lambda c: c["duration"] if c["path"] in same else -1)

    def inproc_file() -> dict:
        req = QueryRequest(clip=held.name, start=a, end=b, out=str(work / "out-file"))
        return query.fn(cfg, req, plan_query(cfg, req, read_motion(held)))

    def inproc_indexed() -> dict:
        m = indexed["duration"] / 2
        req = QueryRequest(clip=indexed["path"], start=m - 0.5, end=m + 0.5, out=str(work / "out-indexed"))
        return query.fn(cfg, req, plan_query(cfg, req))

    res = inproc_file()  # warm-up
    inproc_indexed()
    rows = []
    for label, fn in (("query file, in-process", inproc_file), ("indexed clip, in-process (floor)", inproc_indexed)):
        ts = []
        for _ in range(args.repeat):
            t = time.perf_counter()
            fn()
            ts.append(time.perf_counter() - t)
        rows.append((label, statistics.median(ts)))
    cli = [timed_cli(["search", str(cfg_path), "--query-file", str(held), "--start", f"{a:.3f}", "--end", f"{b:.3f}",
                      "--out", str(work / "out-cli")], work) for _ in range(args.repeat)]
    rows.append(("query file, CLI cold (target ≤ 2 s)", statistics.median(cli)))
    rows += app_rows(cfg, held, a, b, args.repeat)
    print(f"\n{os.cpu_count()} cores, load {os.getloadavg()[0]:.1f}; index: {n} clips, {len(gen.webs)} webs; "
          f"held out {args.held} ({motion.duration:.1f} s, {motion.n_frames} frames); query {a:.2f}-{b:.2f} s; "
          f"webs built on demand: {len(same)}; median of {args.repeat}")
    print("| what | seconds |\n|---|---|")
    for label, s in rows:
        print(f"| {label} | {s:.2f} |")
    top = res["matches"][:5]
    print("top matches of the query file:", ", ".join(f"{m['clip']} ({m['category']})" for m in top))


def app_rows(cfg, held: Path, a: float, b: float, repeat: int) -> list[tuple[str, float]]:
    """The same query in ``motionweb app`` (its API in this process, its search and session workers
    child processes, warmed first by one search of an indexed clip and one of an upload): a new upload of the held-out trial
    (each repeat's AMC differs by a comment line: a new content id, its webs built anew) and its
    first search, then another window of the same upload (its webs kept)."""
    from fastapi.testclient import TestClient
    from motionweb.flows.app.api import create_app
    from motionweb.flows.app.engine import Engine

    asf = next(held.parent.glob("*.asf")).read_text()
    amc = held.read_text()
    first, upload, again = [], [], []
    with TestClient(create_app(Engine(cfg))) as client:
        warm = client.get("/api/catalog", params={"limit": 1}).json()["clips"][0]
        r = client.post("/api/search", json={"clip": warm["path"], "start": 0.0, "end": 1.0})
        up = client.post("/api/uploads", json={"name": held.name, "asf": asf, "amc": amc + "# bench warm-up\n"})
        r2 = client.post("/api/search", json={"clip": up.json().get("id", "?"), "start": a, "end": b})
        if r.status_code != 200 or r2.status_code != 200:  # the workers started, their kernels loaded
            raise SystemExit(f"bench: the app's warm-up searches failed: {r.text[:300]} {r2.text[:300]}")
        for i in range(repeat):
            t = time.perf_counter()
            up = client.post("/api/uploads", json={"name": held.name, "asf": asf, "amc": amc + f"# bench {i}\n"})
            t1 = time.perf_counter()
            r = client.post("/api/search", json={"clip": up.json().get("id", "?"), "start": a, "end": b})
            t2 = time.perf_counter()
            r2 = client.post("/api/search", json={"clip": up.json().get("id", "?"), "start": a - 1.0, "end": b - 1.0})
            t3 = time.perf_counter()
            if up.status_code != 200 or r.status_code != 200 or r2.status_code != 200 or not r.json()["matches"]:
                raise SystemExit(f"bench: the app's upload search failed: {up.text[:300]} {r.text[:300]}")
            upload.append(t1 - t)
            first.append(t2 - t)
            again.append(t3 - t2)
    return [("app: upload (parse in the session worker)", statistics.median(upload)),
            ("app: upload + first search, webs built (target ≤ 2 s)", statistics.median(first)),
            ("app: another window of the upload (webs kept)", statistics.median(again))]


if __name__ == "__main__":
    main()
