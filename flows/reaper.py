"""Services die with the CLI: a watchdog process ends the CLI's descendants when it dies.

The CLI starts Prefect's API server and Dask worker processes as its children. Killed outright
(an out-of-memory kill, ``kill -9``) the CLI runs no cleanup and they would live on, orphaned.
:func:`start_reaper` spawns one small watchdog in its own session: every
:data:`POLL_S` it records the CLI's descendants (pid and start time, from /proc) and, once the
CLI is gone, sends each one still alive SIGTERM, then SIGKILL after :data:`GRACE_S`. Linux only
(elsewhere a no-op); a descendant started less than one poll before the kill may be missed.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

POLL_S = 0.5
GRACE_S = 3.0
_started: set[int] = set()


def _children_table() -> dict[int, list[tuple[int, str]]]:
    """ppid -> [(pid, start time)] of every process, from /proc/<pid>/stat."""
    table: dict[int, list[tuple[int, str]]] = {}
    for name in os.listdir("/proc"):
        if not name.isdigit():
            continue
        try:
            with open(f"/proc/{name}/stat") as fh:
                fields = fh.read().rsplit(")", 1)[1].split()
        except OSError:
            continue
        table.setdefault(int(fields[1]), []).append((int(name), fields[19]))
    return table


def descendants(pid: int) -> set[tuple[int, str]]:
    """(pid, start time) of every process below ``pid``."""
    table = _children_table()
    out: set[tuple[int, str]] = set()
    stack = [pid]
    while stack:
        for child in table.get(stack.pop(), []):
            if child not in out:
                out.add(child)
                stack.append(child[0])
    return out


def _start_time(pid: int) -> str | None:
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[19]
    except OSError:
        return None


def _alive(procs: set[tuple[int, str]]) -> set[tuple[int, str]]:
    return {(p, t) for p, t in procs if _start_time(p) == t}


def watch(parent: int) -> None:
    """The watchdog's loop (runs in its own process): follow ``parent``'s descendants until it
    dies, then end those still running."""
    born = _start_time(parent)
    known: set[tuple[int, str]] = set()
    while _start_time(parent) == born and born is not None:
        known = _alive(known) | descendants(parent)
        time.sleep(POLL_S)
    known.discard((os.getpid(), _start_time(os.getpid()) or ""))
    for sig, wait in ((signal.SIGTERM, GRACE_S), (signal.SIGKILL, 0.0)):
        left = _alive(known)
        for p, _ in left:
            try:
                os.kill(p, sig)
            except OSError:
                pass
        deadline = time.monotonic() + wait
        while _alive(left) and time.monotonic() < deadline:
            time.sleep(0.1)


def start_reaper() -> None:
    """Start the watchdog of this process once (Linux only)."""
    pid = os.getpid()
    if pid in _started or not sys.platform.startswith("linux"):
        return
    _started.add(pid)
    subprocess.Popen([sys.executable, "-m", "motionweb.flows.reaper", str(pid)], start_new_session=True,
                     stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


if __name__ == "__main__":
    watch(int(sys.argv[1]))
