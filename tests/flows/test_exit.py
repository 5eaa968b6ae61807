"""Commands always exit (issue 22, parts 4 and 6): a script that runs ``motionweb index`` with
``capture_output=True`` gets the return code of a CLI killed by SIGSEGV or SIGKILL within 10 s, no process the command started is left, and a crash prints one line naming
the fault and its report (flows/runtime/guard.py, flows/runtime/reaper.py).

The CLI is killed from outside, once its Prefect server answers (and, with process workers, once
a Dask worker process runs): a SIGSEGV sent with kill() meets the same faulthandler as a real one.
Processes the command started are found by a marker variable in their environment
(/proc/<pid>/environ), which every descendant inherits, orphaned or not.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest
import yaml
from fixtures import tiny_index_config
from motionweb.flows.runtime.history import answers
from motionweb.flows.runtime.reaper import descendants

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")

MARK = "MOTIONWEB_EXIT_TEST"

#: the caller: runs the command as a pipeline or notebook does, then counts what is left
SCRIPT = """
import json, os, subprocess, sys, time
mark = os.environ["MOTIONWEB_EXIT_TEST"]
r = subprocess.run(sys.argv[1:], capture_output=True, text=True)
done = time.time()
left = []
for name in os.listdir("/proc"):
    if name.isdigit() and int(name) != os.getpid():
        try:
            with open(f"/proc/{name}/environ", "rb") as fh:
                if f"MOTIONWEB_EXIT_TEST={mark}".encode() in fh.read().split(b"\\0"):
                    with open(f"/proc/{name}/cmdline", "rb") as fh:
                        left.append(fh.read().replace(b"\\0", b" ").decode()[:120])
        except OSError:
            pass
print(json.dumps({"rc": r.returncode, "done": done, "left": left, "stdout": r.stdout, "stderr": r.stderr}))
"""


def marked(marker: str) -> dict[int, str]:
    """pid -> command line of every live process whose environment carries ``MARK=marker``."""
    out = {}
    for name in os.listdir("/proc"):
        if not name.isdigit():
            continue
        try:
            with open(f"/proc/{name}/stat") as fh:
                if fh.read().rsplit(")", 1)[1].split()[0] == "Z":
                    continue
            with open(f"/proc/{name}/environ", "rb") as fh:
                if f"{MARK}={marker}".encode() not in fh.read().split(b"\0"):
                    continue
            with open(f"/proc/{name}/cmdline", "rb") as fh:
                out[int(name)] = fh.read().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            pass
    return out


def cli_command() -> list[str]:
    """The console script beside this interpreter (what users run), else ``python -m``."""
    exe = Path(sys.executable).parent / "motionweb"
    return [str(exe)] if exe.is_file() else [sys.executable, "-m", "motionweb.flows.commands.cli"]


def clean_env(tmp_path: Path, marker: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("PREFECT_API")}
    env.update({MARK: marker, "PREFECT_HOME": str(tmp_path / "prefect"), "MOTIONWEB_APP_DIR": str(tmp_path / "disc"),
                "MOTIONWEB_LOG_DIR": str(tmp_path / "logs")})
    return env


def healthy(cmdline: str) -> bool:
    """Whether the uvicorn of ``cmdline`` (Prefect's temporary server) answers /api/health."""
    args = cmdline.split()
    if "uvicorn" not in args or "--port" not in args[:-1]:
        return False
    return answers(f"http://127.0.0.1:{args[args.index('--port') + 1]}/api", timeout=1)


def run_killed(cmd: list[str], env: dict[str, str], sig: int, need_dask: bool = False) -> dict:
    """Run ``cmd`` under :data:`SCRIPT`, kill the CLI with ``sig`` once its Prefect server answers
    (and a Dask worker runs, with ``need_dask``); the script's report plus the kill time, the
    seconds until nothing marked is left, and what the CLI had started."""
    marker = env[MARK]
    script = subprocess.Popen([sys.executable, "-c", SCRIPT, *cmd], env=env, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        deadline = time.monotonic() + 240
        cli = None
        while time.monotonic() < deadline and script.poll() is None:
            kids = [p for p, _ in descendants(script.pid)]
            cli = cli or next((p for p in kids if _ppid(p) == script.pid), None)
            lines = marked(marker)
            server = any(healthy(c) for c in lines.values() if "uvicorn" in c)
            dask = any("multiprocessing" in c for c in lines.values())
            if cli and server and (dask or not need_dask):
                break
            time.sleep(0.2)
        assert cli is not None and script.poll() is None, "the command ended before it could be killed"
        started = {p: c for p, c in marked(marker).items() if p != script.pid}
        os.kill(cli, sig)
        killed = time.time()
        out, _ = script.communicate(timeout=120)
        gone = time.monotonic() + 30
        while marked(marker) and time.monotonic() < gone:
            time.sleep(0.1)
        res = json.loads(out)
        res.update(killed=killed, all_gone_s=time.time() - killed, left_after=marked(marker), started=started)
        return res
    finally:
        for p in marked(marker):
            try:
                os.kill(p, signal.SIGKILL)
            except OSError:
                pass
        if script.poll() is None:
            script.kill()
            script.wait()


def _live(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie does not)."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def _ppid(pid: int) -> int | None:
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return int(fh.read().rsplit(")", 1)[1].split()[1])
    except OSError:
        return None


def short(cmdlines) -> list[str]:
    """What each command line runs, in a word (``uvicorn``, ``motionweb.flows.runtime.reaper``, ...)."""
    return sorted(next((a for a in c.split()[1:] if not a.startswith("-")), c.split()[0]).rsplit("/", 1)[-1]
                  for c in cmdlines)


def report_of(stderr: str) -> Path:
    """The report named by the one crash line (the last line of stderr, the only ``error:`` one)."""
    errors = [ln for ln in stderr.splitlines() if ln.startswith("error:")]
    assert len(errors) == 1 and stderr.rstrip().endswith(errors[0]), stderr
    assert "Traceback" not in stderr, stderr
    return Path(errors[0].rsplit("; report: ", 1)[1])


@pytest.mark.parametrize("sig", [signal.SIGSEGV, signal.SIGKILL], ids=["SIGSEGV", "SIGKILL"])
def test_a_killed_index_returns_at_once_and_leaves_nothing(app_store: Path, tmp_path: Path, sig: int) -> None:
    """``motionweb index`` (thread workers) under ``capture_output=True``, killed once its Prefect
    server is up. (``search`` was the command here: it starts no Prefect server any more when
    none is configured, issue 23.)"""
    cfg = yaml.safe_load(app_store.read_text())
    tmp_cfg = tmp_path / "config.yaml"  # the demo corpus, a store and output folder of this test's own
    cfg.update(store={"path": str(tmp_path / "store")}, output=str(tmp_path / "out"))
    cfg["corpus"]["path"] = str(app_store.parent / "corpus")
    tmp_cfg.write_text(yaml.safe_dump(cfg))
    res = run_killed([*cli_command(), "index", str(tmp_cfg), "--no-progress"],
                     clean_env(tmp_path, uuid.uuid4().hex), sig)
    print(f"{signal.Signals(sig).name}: rc {res['rc']} after {res['done'] - res['killed']:.2f} s, "
          f"{len(res['left'])} left at return {short(res['left'])}, all gone after {res['all_gone_s']:.2f} s; "
          f"started {short(res['started'].values())}")
    assert res["rc"] == -sig
    assert res["done"] - res["killed"] < 10
    assert any("uvicorn" in c for c in res["started"].values())
    assert not res["left_after"], res["left_after"]
    assert res["all_gone_s"] < 10
    logs = tmp_path / "out" / "logs"
    if sig == signal.SIGSEGV:
        report = report_of(res["stderr"])
        assert report.parent == logs and report.read_text().startswith("Fatal Python error: Segmentation fault")
        assert "error: motionweb index crashed (Segmentation fault) in " in res["stderr"]
        assert [p.name for p in logs.iterdir() if not p.name.startswith("stdio-")] == [report.name]
    else:
        assert "error:" not in res["stderr"] and "Traceback" not in res["stderr"], res["stderr"]
        assert not list(logs.glob("crash-*")), "an empty report is removed"


def test_a_crashed_index_returns_at_once_and_leaves_no_worker(tmp_path: Path) -> None:
    """``motionweb index`` with Dask process workers, SIGSEGV once a worker and the server run."""
    tiny_index_config(tmp_path)
    res = run_killed([*cli_command(), "index", str(tmp_path / "c.yaml"), "--no-progress"],
                     clean_env(tmp_path, uuid.uuid4().hex), signal.SIGSEGV, need_dask=True)
    print(f"index SIGSEGV: rc {res['rc']} after {res['done'] - res['killed']:.2f} s, {len(res['left'])} left at "
          f"return {short(res['left'])}, all gone after {res['all_gone_s']:.2f} s; started {short(res['started'].values())}")
    assert res["rc"] == -signal.SIGSEGV
    assert res["done"] - res["killed"] < 10
    assert not res["left_after"] and res["all_gone_s"] < 10, res["left_after"]
    assert report_of(res["stderr"]).parent == tmp_path / "out" / "logs"


def test_a_crash_is_one_line_naming_the_fault_and_its_report(tmp_path: Path) -> None:
    """A real segmentation fault in the console script: one line, the frame, the report."""
    code = "import faulthandler, motionweb.flows.commands.cli as c\nc.app = faulthandler._sigsegv\nc.main()\n"
    env = clean_env(tmp_path, uuid.uuid4().hex)
    t = time.monotonic()
    r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=60,
                       check=False)
    took = time.monotonic() - t
    print(f"rc {r.returncode} in {took:.2f} s: {r.stderr.strip()}")
    assert r.returncode == -signal.SIGSEGV and took < 10
    assert r.stderr.count("\n") == 1 and r.stderr.startswith("error: motionweb crashed (Segmentation fault)")
    report = report_of(r.stderr)
    assert report.parent == tmp_path / "logs"
    assert "Fatal Python error: Segmentation fault" in report.read_text()
    deadline = time.monotonic() + 10
    while any(p.name.startswith("stdio-") for p in report.parent.iterdir()) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert [p.name for p in report.parent.iterdir()] == [report.name], "the empty log is removed"
    shutil.rmtree(report.parent)
