"""The on-demand commands' runs in Prefect's history, recorded after the answer (issue 23).

``motionweb warp``, ``retime``, ``search`` and ``parameterize`` do their work in the CLI's own
process, without Prefect (flows/runtime/lazy_prefect.py), and print their answer. Then, only when a Prefect
server is configured or already running, :func:`record_run` records the run as a Prefect flow run
of the same name as the command's flow (``guided-warp``, ``retime``, ``query``, ``parameterize``)
with its parameters and outcome (or its error) in the run's log and result: the service's
recording flow (:func:`motionweb.flows.app.recorder.app_query`, renamed), against the server found
the way the service finds one (:class:`motionweb.flows.app.recorder.PrefectServer`): the
configured ``PREFECT_API_URL``, else one answering at Prefect's default local address. With no
server nothing is recorded and nothing is started; the outputs are the same bytes either way.

Recording is synchronous, after the answer is printed and the outputs are written: a process
detached from the CLI would be ended by the CLI's watchdog (flows/runtime/reaper.py) when the CLI exits,
and one flow run against a running server costs about a second. A server that is configured but
does not answer, or a record that fails, costs one warning line on stderr, never the exit code.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import sys
import tomllib
import urllib.request
from pathlib import Path
from typing import Any

#: Prefect's default local server (``prefect server start``), as flows/app/recorder.py looks for it
DEFAULT_API_URL = "http://127.0.0.1:4200/api"


def answers(api_url: str, timeout: float = 2.0) -> bool:
    """Whether a Prefect API answers at ``api_url`` (``.../api``): the one probe, used by the CLI
    here and by the service's recorder (``flows/app/recorder.py``); this module imports no Prefect
    (seconds), the cost it saves when no server is there."""
    try:
        with urllib.request.urlopen(api_url.rstrip("/") + "/health", timeout=timeout) as r:
            return r.status == 200
    except (OSError, ValueError):
        return False


def configured_api_url() -> str | None:
    """``PREFECT_API_URL`` as Prefect would read it: the environment; Prefect's current settings
    when Prefect is already imported (e.g. a test harness's temporary settings); else the active
    profile of ``$PREFECT_HOME/profiles.toml`` (``prefect config set PREFECT_API_URL=...``)."""
    if os.environ.get("PREFECT_API_URL"):
        return os.environ["PREFECT_API_URL"]
    if "prefect.settings" in sys.modules:
        from prefect.settings import get_current_settings

        url = get_current_settings().api.url
        return str(url) if url else None
    home = Path(os.environ.get("PREFECT_HOME") or Path.home() / ".prefect").expanduser()
    try:
        profiles = tomllib.loads((home / "profiles.toml").read_text())
    except (OSError, tomllib.TOMLDecodeError):
        return None
    active = os.environ.get("PREFECT_PROFILE") or profiles.get("active") or "ephemeral"
    url = profiles.get("profiles", {}).get(active, {}).get("PREFECT_API_URL")
    return str(url) if url else None


def server_url() -> str | None:
    """The Prefect API to record to: the configured one, else one answering at
    :data:`DEFAULT_API_URL`, else None (no server: nothing is recorded)."""
    url = configured_api_url()
    if url:
        return url
    return DEFAULT_API_URL if answers(DEFAULT_API_URL, timeout=1.0) else None


def _jsonable(value: Any) -> Any:
    return json.loads(json.dumps(value, default=str))


@contextlib.contextmanager
def prefect_console_muted():
    """Mute Prefect's console log handlers for the block: a record's own log lines go to the
    server, not to the user's terminal, which has the command's answer already.

    Prefect also builds its console handler once, on the stream that was ``sys.stderr`` when
    Prefect was first imported; when that stream was replaced and closed since (a test runner's
    captured stream), an unmuted line would print "--- Logging error --- Traceback"."""
    loggers = [logging.root, *[lg for n, lg in logging.root.manager.loggerDict.items()
                               if n == "prefect" or n.startswith("prefect.")]]
    handlers = []
    for lg in loggers:  # Prefect's console handler sits on the root logger, its own on prefect.*
        for h in getattr(lg, "handlers", []):
            if isinstance(h, logging.StreamHandler) and type(h).__module__.startswith("prefect") and h not in handlers:
                handlers.append(h)
    saved = [(h, h.level) for h in handlers]
    try:
        for h, _ in saved:
            h.setLevel(logging.CRITICAL + 1)
        yield
    finally:
        for h, level in saved:
            h.setLevel(level)


def record_run(flow_name: str, parameters: dict[str, Any], outcome: dict[str, Any]) -> bool:
    """Record one command run as a Prefect flow run named ``flow_name`` when a server is there
    (see the module notes); whether it was recorded."""
    url = server_url()
    if url is None:
        return False
    import typer

    if not answers(url):
        typer.secho(f"warning: the Prefect server at {url} does not answer: this run is not recorded",
                    err=True, fg=typer.colors.YELLOW)
        return False
    try:
        from motionweb.flows.app.recorder import app_query
        from prefect.settings import PREFECT_API_URL, PREFECT_FLOWS_HEARTBEAT_FREQUENCY, temporary_settings

        with temporary_settings({PREFECT_API_URL: url, PREFECT_FLOWS_HEARTBEAT_FREQUENCY: None}), \
                prefect_console_muted():
            app_query.with_options(name=flow_name)(flow_name, _jsonable(parameters), _jsonable(outcome))
    except Exception as exc:  # noqa: BLE001 - a record lost must not fail a command that succeeded
        first = (str(exc).strip().splitlines() or [""])[0]
        typer.secho(f"warning: this run was not recorded in Prefect at {url} ({type(exc).__name__}: {first})",
                    err=True, fg=typer.colors.YELLOW)
        return False
    return True
