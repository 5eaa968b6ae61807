"""Services die with the CLI: a watchdog process ends the CLI's descendants when it dies, and
says so in one line when the CLI crashed.

The CLI starts Prefect's API server and Dask worker processes as its children. Killed outright
(an out-of-memory kill, ``kill -9``, a segmentation fault) the CLI runs no cleanup and they would
live on, orphaned. :func:`start_reaper` spawns one small watchdog in its own session: every
:data:`POLL_S` it records the CLI's descendants (pid and start time, from /proc) and, once the
CLI is gone, sends each one still alive SIGTERM, then SIGKILL after :data:`GRACE_S`. Linux only
(elsewhere a no-op); a descendant started less than one poll before the kill may be missed.

Gone means no /proc entry with the CLI's start time, *or* a zombie (state ``Z``, the third field
of ``/proc/<pid>/stat``): a CLI that died but whose parent has not reaped it yet (a script blocked
reading its pipes, say) still has its /proc entry and start time, and is just as dead.

With a channel (``start_reaper(stderr=...)``, used by :mod:`motionweb.flows.runtime.guard`) the watchdog
also reads lines from the CLI on its stdin, a pipe only the CLI holds, so the CLI's death is an
end-of-file seen at once rather than at the next poll:

- ``command TEXT``: what the CLI runs (``motionweb search``), for the crash line;
- ``report PATH``: the file Python's faulthandler writes the CLI's crash report to (the last one
  given is the current one);
- ``clean PATH``: a file (or folder) to remove after the CLI has died if it is empty.

When the CLI is gone and its report is not empty (faulthandler wrote it: SIGSEGV, SIGABRT, SIGBUS,
SIGILL, SIGFPE) the watchdog prints one line on the caller's stderr (:func:`crash_line`), then
closes that stderr before ending the descendants, so that the caller's pipes see their end as soon
as the CLI is gone. The watchdog never holds the caller's stdin or stdout.
"""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

POLL_S = 0.5
GRACE_S = 3.0
#: pid -> write end of its watchdog's channel (None: a watchdog without one)
_started: dict[int, int | None] = {}


def _stat(pid: int | str) -> list[str] | None:
    """The fields of ``/proc/<pid>/stat`` after the command name (state first), None if gone."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None


def _children_table() -> dict[int, list[tuple[int, str]]]:
    """ppid -> [(pid, start time)] of every live (not zombie) process, from /proc/<pid>/stat."""
    table: dict[int, list[tuple[int, str]]] = {}
    for name in os.listdir("/proc"):
        if not name.isdigit():
            continue
        fields = _stat(name)
        if fields is None or fields[0] == "Z":
            continue
        table.setdefault(int(fields[1]), []).append((int(name), fields[19]))
    return table


def descendants(pid: int) -> set[tuple[int, str]]:
    """(pid, start time) of every live process below ``pid``."""
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
    """The start time of a live process; None when it is gone or a zombie (dead, not yet reaped)."""
    fields = _stat(pid)
    return None if fields is None or fields[0] == "Z" else fields[19]


def _alive(procs: set[tuple[int, str]]) -> set[tuple[int, str]]:
    return {(p, t) for p, t in procs if _start_time(p) == t}


class Channel:
    """The lines the CLI sends on the watchdog's stdin (see the module notes)."""

    def __init__(self, fd: int):
        self.fd, self.buf, self.eof = fd, b"", False
        self.command, self.report = "motionweb", None
        self.clean: list[str] = []

    def wait(self, timeout: float) -> bool:
        """Read what arrives within ``timeout`` seconds; False when nothing did (True at once on
        end-of-file)."""
        ready, _, _ = select.select([self.fd], [], [], timeout)
        if not ready:
            return False
        data = os.read(self.fd, 65536)
        if not data:
            self.eof = True
            return True
        *lines, self.buf = (self.buf + data).split(b"\n")
        for raw in lines:
            key, _, value = raw.decode("utf-8", "replace").partition(" ")
            if key == "command":
                self.command = value
            elif key == "report":
                self.report = value
            elif key == "clean":
                self.clean.append(value)
        return True


def crash_line(command: str, report: str) -> str | None:
    """One line naming a crash from faulthandler's report (None when the report is empty), e.g.
    ``error: motionweb search crashed (Segmentation fault) in _walk_arrays (tasks/search.py:88);
    report: /out/logs/crash-....txt``: the fault and the innermost Python frame of the thread that
    crashed (a compiled kernel has no frame of its own: its caller is named)."""
    try:
        text = Path(report).read_text(errors="replace")
    except OSError:
        return None
    lines = [ln.strip() for ln in text.splitlines()]
    if not any(lines):
        return None
    fault = next((ln.split(":", 1)[1].strip() for ln in lines if ln.startswith("Fatal Python error:")),
                 "a fatal error")
    current = next((i for i, ln in enumerate(lines) if ln.startswith("Current thread")), 0)
    where = ""
    for ln in lines[current:]:
        if ln.startswith("File "):  # File "/x/tasks/search.py", line 88 in _walk_arrays
            path, _, rest = ln[len('File "'):].partition('", line ')
            lineno, _, func = rest.partition(" in ")
            short = "/".join(Path(path).parts[-2:])
            where = f" in {func} ({short}:{lineno})"
            break
    return f"error: {command} crashed ({fault}){where}; report: {report}"


def _remove_if_empty(paths: list[str]) -> None:
    """Remove each empty file, then each empty folder (innermost first); anything else stays."""
    for p in paths:
        try:
            if os.path.isfile(p) and os.path.getsize(p) == 0:
                os.remove(p)
        except OSError:
            pass
    for p in sorted((p for p in paths if os.path.isdir(p)), key=len, reverse=True):
        try:
            os.rmdir(p)
        except OSError:
            pass


def watch(parent: int, channel: bool = False) -> None:
    """The watchdog's loop (runs in its own process): follow ``parent``'s descendants until it
    dies, print the crash line (with a channel), then end those still running."""
    born = _start_time(parent)
    known: set[tuple[int, str]] = set()
    chan = Channel(0) if channel else None
    while born is not None and _start_time(parent) == born:
        known = _alive(known) | descendants(parent)
        if chan is None or chan.eof:
            time.sleep(0.05 if chan is not None else POLL_S)  # after the end-of-file: dying now
        else:
            chan.wait(POLL_S)
    known.discard((os.getpid(), _start_time(os.getpid()) or ""))
    if chan is not None:
        while not chan.eof and chan.wait(0.2):  # whatever the CLI wrote last
            pass
        line = crash_line(chan.command, chan.report) if chan.report else None
        if line:
            try:
                os.write(2, (line + "\n").encode())
            except OSError:
                pass
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, 2)  # the caller's stderr is released before the grace period
        os.close(devnull)
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
    if chan is not None:
        _remove_if_empty(chan.clean)


def start_reaper(stderr: int | None = None) -> int | None:
    """Start the watchdog of this process once (Linux only).

    With ``stderr`` (a file descriptor: the caller's stderr) the watchdog gets a channel and may
    print the crash line there; the write end of that channel is returned (non-inheritable: only
    this process holds it). Without, the watchdog's stdio are all /dev/null and None is returned.
    """
    pid = os.getpid()
    if pid in _started or not sys.platform.startswith("linux"):
        return _started.get(pid)
    args = [sys.executable, "-m", "motionweb.flows.runtime.reaper", str(pid)]
    if stderr is None:
        _started[pid] = None
        subprocess.Popen(args, start_new_session=True, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                         stderr=subprocess.DEVNULL)
        return None
    read, write = os.pipe()  # both non-inheritable; Popen hands ``read`` to the child as its stdin
    try:
        subprocess.Popen([*args, "--channel"], start_new_session=True, stdin=read,
                         stdout=subprocess.DEVNULL, stderr=stderr)
    except OSError:
        os.close(write)
        raise
    finally:
        os.close(read)
    _started[pid] = write
    return write


if __name__ == "__main__":
    watch(int(sys.argv[1]), channel="--channel" in sys.argv[2:])
