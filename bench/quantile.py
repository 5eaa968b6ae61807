"""Benchmark: ε as a quantile of a scope's web values, moved like the app's slider, this checkout
against a previous revision in the same run (issue 25, part 5; design §5).

A search worker (``flows.app.worker._State``, as the service runs it: a bounded cache, a file
cache in a fresh temporary folder) opens one category of ``--store`` and asks the scope's
quantiles ``--qs`` one after another (the first needs one pass over every web of the scope; the
previous code made one per new quantile), then a second worker process asks one more quantile
(a service started later on the kept files). Each code runs in its own child process: the
previous revision ``--base`` (``git archive`` of it put first on PYTHONPATH, bench/app_scale.py)
and this checkout. Printed: seconds per ask and the value, which must be the same for both codes
(checked), with the scope's webs and values counted (the floor: numpy's quantile of the values
held in memory, measured here).

    .venv/bin/python -m bench.quantile --store DIR [--category hop] [--base REV] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from bench.app_scale import base_code
from bench.corpus import CorpusError

CHILD = r"""
import json, sys, time, numpy as np
from motionweb.flows.app.worker import _State
from motionweb.store.generations import current_generation
from motionweb.store.zarr_store import MotionStore
url, cat, folder, qs, q_last = sys.argv[1], sys.argv[2], sys.argv[3], json.loads(sys.argv[4]), float(sys.argv[5])
gen = current_generation(MotionStore(url, read_only=True), lean=True)
out = {"asks": []}
for run, asks in ((0, qs), (1, [q_last])):
    st = _State(url, 256 * 2**20, (folder, 4 * 2**30))
    sc = st.scope(gen.id, cat)
    st.warm(gen.id, cat)
    for q in asks:
        t = time.perf_counter()
        v = sc.search.quantile(q, stream=True)
        out["asks"].append([run, q, time.perf_counter() - t, v])
out["webs"] = len(sc.webs.records())
vals = np.concatenate(sc.webs.map_webs(lambda w: w.paths_values.copy()))
t = time.perf_counter()
np.quantile(vals, qs[0])
out["floor_s"], out["values"] = time.perf_counter() - t, int(vals.size)
print("RESULT " + json.dumps(out))
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--store", required=True)
    ap.add_argument("--category", default="hop")
    ap.add_argument("--qs", type=float, nargs="+", default=[0.05, 0.37, 0.8, 0.5])
    ap.add_argument("--then", type=float, default=0.61, help="the quantile a second process asks")
    ap.add_argument("--base", default="d6fdd3e")
    ap.add_argument("--keep", help="work folder (the base code), reused when present")
    args = ap.parse_args()
    work = Path(args.keep or tempfile.mkdtemp(prefix="motionweb-bench-quantile-"))
    work.mkdir(parents=True, exist_ok=True)
    results = {}
    for name, pkg in ((args.base[:10], base_code(work, args.base)), ("this", None)):
        env = {**os.environ}
        env.pop("PYTHONPATH", None)
        if pkg is not None:
            env["PYTHONPATH"] = str(pkg)
        with tempfile.TemporaryDirectory(prefix="motionweb-files-") as folder:
            r = subprocess.run([sys.executable, "-c", CHILD, str(Path(args.store).resolve()), args.category, folder,
                                json.dumps(args.qs), str(args.then)], capture_output=True, text=True, env=env, check=False)
        line = next((x for x in r.stdout.splitlines() if x.startswith("RESULT ")), None)
        if r.returncode != 0 or line is None:
            raise CorpusError(f"{name}: the quantile child failed ({r.returncode}): {r.stderr[-2000:]}")
        results[name] = json.loads(line[len("RESULT "):])
    first = next(iter(results.values()))
    if first["webs"] == 0:
        raise CorpusError(f"category {args.category!r} has no webs in {args.store}")
    print(f"store {args.store}, category {args.category}: {first['webs']} webs, {first['values']} path values; "
          f"floor (numpy's quantile of the values in memory) {first['floor_s'] * 1000:.0f} ms; "
          f"{os.cpu_count()} cores, load {os.getloadavg()[0]:.1f}")
    print(f"{'process':>8} {'q':>6} " + " ".join(f"{n + ' s':>12}" for n in results) + "  value")
    for asks in zip(*(res["asks"] for res in results.values()), strict=True):
        run, q, value = asks[0][0], asks[0][1], asks[0][3]
        if any(a[3] != value for a in asks):
            raise CorpusError(f"q={q}: the codes disagree: {[a[3] for a in asks]}")
        print(f"{'first' if run == 0 else 'second':>8} {q:6.3f} " + " ".join(f"{a[2]:12.3f}" for a in asks)
              + f"  {value:.6g}")
    print(f"load at the end {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
