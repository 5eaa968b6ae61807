"""Benchmark: ``motionweb demo`` on a fresh machine, with and without the kernel warm-up (issue 23:
"``motionweb demo`` takes ≤ 30 s after the install on a quiet machine, numba compilation included").

Each run is a new ``motionweb demo`` process in a folder of its own, with a fresh state where the
row says so:

* ``fresh, warm-up``: an empty numba cache (``NUMBA_CACHE_DIR``) and a new Prefect home
  (``PREFECT_HOME``: no database yet, as after the install), the warm-up on (the default:
  flows/runtime/warmup.py compiles the kernels in parallel processes and starts Prefect's local server
  while the corpus is written);
* ``fresh, no warm-up``: the same with ``MOTIONWEB_WARMUP=0``, the previous code's behaviour
  (every kernel compiled on first use on one thread), measured in the same run as the baseline;
* ``cached``: the kernels and the Prefect database of the first row kept: the demo's own work
  and start-ups, the floor the fresh runs approach.

Rows alternate (fresh warm-up, fresh without, ...) for ``--repeat`` rounds; the table gives each
row's min / median / max wall time and CPU time (user + system of the process tree). A run that
exits non-zero, or whose output lacks the corpus (27 clips, 9 categories) or the search's
matches, stops the benchmark (exit 1). No Prefect server may be configured (``PREFECT_API_URL``
is removed from the runs' environment).

    env -u OPENBLAS_CORETYPE -u OPENBLAS_L2_SIZE .venv/bin/python -m bench.demo [--repeat 2]
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

MOTIONWEB = [sys.executable, "-c", "from motionweb.flows.commands.cli import main; main()"]
TARGET_S = 30.0


def run(work: Path, name: str, numba_cache: Path, prefect_home: Path, warm: bool) -> tuple[float, float, float]:
    """One demo run: (wall s, CPU s of its process tree, the index's own wall s)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("PREFECT_API_URL")}
    env.update(NUMBA_CACHE_DIR=str(numba_cache), PREFECT_HOME=str(prefect_home),
               MOTIONWEB_WARMUP="1" if warm else "0", PREFECT_SERVER_ANALYTICS_ENABLED="false")
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    r = subprocess.run([*MOTIONWEB, "demo", "--workdir", str(work / name)], env=env, capture_output=True,
                       text=True, timeout=900)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    out = r.stdout + r.stderr
    if r.returncode != 0:
        sys.exit(f"bench.demo: {name} exited {r.returncode}:\n{out[-3000:]}")
    if "27 clips, 9 categories" not in out or not re.search(r"\d+ matches in", out):
        sys.exit(f"bench.demo: {name} did not build the demo it claims (27 clips, 9 categories, matches):\n"
                 f"{out[-3000:]}")
    m = re.search(r"wall time ([\d.]+) s", out)
    return wall, cpu, float(m.group(1)) if m else float("nan")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="bench-demo-"))
    rows: dict[str, list[tuple[float, float, float]]] = {"fresh, warm-up": [], "fresh, no warm-up": [], "cached": []}
    try:
        for i in range(args.repeat):
            for label, warm in (("fresh, warm-up", True), ("fresh, no warm-up", False)):
                tag = f"{'w' if warm else 'n'}{i}"
                rows[label].append(run(work, tag, work / f"numba-{tag}", work / f"prefect-{tag}", warm))
                print(f"  {label} #{i + 1}: {rows[label][-1][0]:.1f} s", file=sys.stderr, flush=True)
        for i in range(args.repeat):  # the first fresh warm-up run's caches, now filled
            rows["cached"].append(run(work, f"c{i}", work / "numba-w0", work / "prefect-w0", True))
        print(f"motionweb demo (27 clips, 6324 frames; {os.cpu_count()} cores, load {os.getloadavg()[0]:.1f}); "
              f"target: fresh ≤ {TARGET_S:g} s")
        print(f"{'run':<20}{'wall min':>10}{'median':>9}{'max':>8}{'CPU median':>12}{'index wall':>12}")
        for label, vals in rows.items():
            walls = [v[0] for v in vals]
            print(f"{label:<20}{min(walls):>10.1f}{statistics.median(walls):>9.1f}{max(walls):>8.1f}"
                  f"{statistics.median(v[1] for v in vals):>12.1f}{statistics.median(v[2] for v in vals):>12.1f}")
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
