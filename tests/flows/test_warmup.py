"""The demo's warm-up (flows/runtime/warmup.py, tasks/warm.py): on a fresh numba cache, ``motionweb demo``
compiles its kernels in the warm-up processes, and its own process compiles none of them."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import yaml
from motionweb.tasks.warm import GROUPS

#: runs ``motionweb demo`` in this process, recording every kernel compiled outside another one's
#: compilation (a call from Python), and writes them as JSON rows in tasks/warm.py's notation
SCRIPT = """
import json, sys
from numba.core import event
from typer.testing import CliRunner

found, depth = [], [0]

class Compiles(event.Listener):
    def on_start(self, ev):
        depth[0] += 1

    def on_end(self, ev):
        depth[0] -= 1
        f = ev.data["dispatcher"].py_func
        if depth[0] == 0 and f.__module__.startswith("motionweb."):
            from motionweb.tasks.warm import format_type
            found.append([f.__module__, f.__name__, " ".join(format_type(a) for a in ev.data["args"])])

event.register("numba:compile", Compiles())
from motionweb.flows.commands.cli import app

res = CliRunner().invoke(app, ["demo", "--workdir", sys.argv[1], "--config", sys.argv[2]])
json.dump({"exit": res.exit_code, "output": res.output, "compiled": found}, open(sys.argv[3], "w"))
"""


def test_demo_compiles_nothing_after_its_warm_up(prefect_harness, tmp_path: Path):
    from prefect.settings import PREFECT_API_URL

    cfg = tmp_path / "small.yaml"  # the demo's config with one clip per category: the same kernels
    cfg.write_text(yaml.safe_dump({"corpus": {"path": "corpus", "length_unit": "m"},
                                   "demo": {"variants_per_category": 2}, "store": {"path": "store"},
                                   "output": "out"}))
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba-cache"), "MOTIONWEB_WARMUP": "1",
           "PREFECT_API_URL": str(PREFECT_API_URL.value())}
    out = tmp_path / "result.json"
    subprocess.run([sys.executable, "-c", SCRIPT, str(tmp_path / "demo"), str(cfg), str(out)], env=env,
                   check=True, timeout=900)
    res = json.loads(out.read_text())
    assert res["exit"] == 0, res["output"]
    assert "4 matches" in res["output"] or "matches in" in res["output"], res["output"]
    # the demo scans its corpus (the BVH reader) and computes its features (the kinematics) before a
    # share could be done: those in-process
    reader = [[m, n, s] for m, n, s, _ in GROUPS["read"]]
    extra = [row for row in res["compiled"] if row not in reader]
    rows = "\n".join(f'("{m}", "{n}", "{s}", ...),' for m, n, s in extra)
    assert not extra, f"compiled on first use despite the warm-up; add to tasks/warm.py GROUPS:\n{rows}"
    assert list((tmp_path / "numba-cache").rglob("*.nbi")), "the warm-up wrote no numba cache"
