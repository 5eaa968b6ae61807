"""A CLI run always exits, and a crash says so in one line: the console script's guard.

:func:`protect` runs first in :func:`motionweb.flows.commands.cli.main`:

1. **Private stdio.** The CLI keeps the caller's stdin, stdout and stderr on descriptors of its own
   (``os.dup``: not inherited by children) and rebinds ``sys.stdin/stdout/stderr`` to them, then
   points descriptors 0, 1 and 2 at /dev/null (0) and a log file (1, 2). Every process the CLI
   starts from then on (Prefect's temporary API server, Dask workers, multiprocessing helpers, the
   service's recorder) inherits the log file, never the caller's pipes. So a script running
   ``subprocess.run([... "motionweb", ...], capture_output=True)`` sees its pipes end when the
   CLI dies, even if a server it started lives on. This is one switch in our own process rather
   than an option per launcher: Prefect 3 starts its ephemeral server with a bare
   ``subprocess.Popen`` (``prefect.server.api.server.SubprocessASGIServer._run_uvicorn_command``)
   that takes no stdio setting, and Dask's nanny spawns workers with inherited stdio too; patching
   each would tie us to their internals. C-level output of the CLI itself (a C library's warning,
   a fatal error before Python's handlers) lands in the log file too, not at the user.
2. **Crash report.** Python's :mod:`faulthandler` writes the tracebacks of a fatal signal
   (SIGSEGV, SIGABRT, SIGBUS, SIGILL, SIGFPE) to a report file.
3. **Watchdog.** :func:`motionweb.flows.runtime.reaper.start_reaper` starts the watchdog with the caller's
   stderr and a channel: when the CLI is gone it prints one line naming the crash and the report
   (only when the report is not empty), releases that stderr, ends the CLI's descendants, and
   removes the log and report files (and the folders made for them) that stayed empty.

Where the files go: ``<output>/logs/`` once a command loads its config (:func:`report_into`, from
:func:`motionweb.flows.commands.cli.config_or_fail`), before that (and for commands without a config) the
folder ``$MOTIONWEB_LOG_DIR``, else ``$XDG_STATE_HOME/motionweb/logs`` (``~/.local/state/...``).
Files are named ``crash-<time>-<pid>.txt`` (the report) and ``stdio-<time>-<pid>.log`` (the
services' and the CLI's low-level output).
"""

from __future__ import annotations

import atexit
import faulthandler
import os
import sys
import time
from pathlib import Path
from typing import IO

from motionweb.flows.runtime.reaper import start_reaper

LOG_DIR_ENV = "MOTIONWEB_LOG_DIR"


class _Run:
    """The protected run's state: its report, its log descriptor and the watchdog's channel."""

    def __init__(self, channel: int | None, stamp: str):
        self.channel, self.stamp = channel, stamp
        self.report: IO[str] | None = None
        self.report_path: Path | None = None
        self.log_path: Path | None = None
        self.folder: Path | None = None


_RUN: _Run | None = None


def default_log_dir() -> Path:
    """``$MOTIONWEB_LOG_DIR``, else ``$XDG_STATE_HOME/motionweb/logs`` (default ``~/.local/state``)."""
    if os.environ.get(LOG_DIR_ENV):
        return Path(os.environ[LOG_DIR_ENV])
    state = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(state) / "motionweb" / "logs"


def _send(line: str) -> None:
    if _RUN is not None and _RUN.channel is not None:
        try:
            os.write(_RUN.channel, (line.replace("\n", " ") + "\n").encode())
        except OSError:
            pass


def _make_folder(folder: Path) -> None:
    """Create ``folder``, telling the watchdog to remove each folder made here if it stays empty."""
    made = []
    p = folder
    while not p.exists() and p != p.parent:
        made.append(p)
        p = p.parent
    folder.mkdir(parents=True, exist_ok=True)
    for m in made:
        _send(f"clean {m}")


def _use_folder(folder: Path) -> bool:
    """Move the report and the log to ``folder`` (new children log there; False if unwritable)."""
    run = _RUN
    assert run is not None
    pid = os.getpid()
    try:
        _make_folder(folder)
        report_path = folder / f"crash-{run.stamp}-{pid}.txt"
        log_path = folder / f"stdio-{run.stamp}-{pid}.log"
        report = open(report_path, "w")  # noqa: SIM115 - open while the run lasts
        log = os.open(log_path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
    except OSError:
        return False
    for fd in _OWNED:
        os.dup2(log, fd)
    os.close(log)
    faulthandler.enable(file=report, all_threads=True)
    old, old_paths = run.report, (run.report_path, run.log_path)
    run.report, run.report_path, run.log_path, run.folder = report, report_path, log_path, folder
    _send(f"report {report_path}")
    _send(f"clean {report_path}")
    _send(f"clean {log_path}")
    if old is not None:
        old.close()
        for p in old_paths:
            if p is not None and p.is_file() and p.stat().st_size == 0:
                p.unlink(missing_ok=True)
    return True


#: descriptors (1, 2) whose caller's stream the CLI keeps privately; they point at the log
_OWNED: set[int] = set()


def _privatize(fd: int, name: str) -> bool:
    """Rebind ``sys.<name>`` to a private copy of descriptor ``fd`` (when that stream uses it)."""
    stream = getattr(sys, name)
    try:
        if stream is None or stream.fileno() != fd:
            return False
        if fd:
            stream.flush()
        own = os.dup(fd)  # non-inheritable
    except (OSError, ValueError, AttributeError):
        return False
    buffering = 1 if getattr(stream, "line_buffering", False) else -1
    setattr(sys, name, open(own, "r" if fd == 0 else "w", buffering=buffering,  # noqa: SIM115 - sys.<name> now
                            encoding=stream.encoding, errors=stream.errors))
    return True


def protect(command: str = "motionweb") -> None:
    """Guard this process as a CLI run (see the module notes); once, POSIX only.

    ``command`` names the run in the crash line (``motionweb search``)."""
    global _RUN
    if _RUN is not None or os.name != "posix":
        return
    private = {fd for fd, name in ((0, "stdin"), (1, "stdout"), (2, "stderr")) if _privatize(fd, name)}
    if 0 in private:
        null = os.open(os.devnull, os.O_RDONLY)
        os.dup2(null, 0)
        os.close(null)
    _OWNED.update(private - {0})
    channel = None
    try:
        channel = start_reaper(stderr=sys.stderr.fileno())
    except (OSError, ValueError, AttributeError):
        pass
    _RUN = _Run(channel, time.strftime("%Y%m%d-%H%M%S"))
    if channel is None:  # no watchdog (not Linux): the empty files are removed at exit
        atexit.register(_remove_empty)
    _send(f"command {command}")
    for folder in (default_log_dir(), Path(os.environ.get("TMPDIR", "/tmp")) / f"motionweb-{os.getuid()}"):
        if _use_folder(folder):
            break
    else:  # nowhere to write: the services' output goes nowhere, faulthandler stays off
        null = os.open(os.devnull, os.O_WRONLY)
        for fd in _OWNED:
            os.dup2(null, fd)
        os.close(null)


def _remove_empty() -> None:
    if _RUN is not None:
        for p in (_RUN.report_path, _RUN.log_path):
            if p is not None and p.is_file() and p.stat().st_size == 0:
                p.unlink(missing_ok=True)


def report_into(output: str | Path) -> None:
    """Put this run's crash report and log in ``<output>/logs/`` (a local output folder; a no-op
    when the run is not protected, e.g. under a test runner)."""
    if _RUN is None or "://" in str(output):
        return
    folder = Path(output) / "logs"
    if _RUN.folder != folder:
        _use_folder(folder)
