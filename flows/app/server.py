"""``motionweb app``: run the service (uvicorn) for one config's store until stopped.

Startup: check the host (loopback unless a token is given), bind the socket (so ``--port 0``
picks a free port and the discovery file names the real one), find or start the Prefect server
(in the background: the API serves at once, records follow when Prefect answers), open the
committed generation (its manifest only) and open its search scopes in the background (in the
search worker processes, :mod:`motionweb.flows.app.worker`, which read webs as searches reach
them), write the discovery file (:mod:`motionweb.flows.app.client`).
Shutdown (Ctrl-C, SIGTERM): remove the discovery file, end the search workers, stop a Prefect
server of our own.
"""

from __future__ import annotations

import contextlib
import ipaddress
import logging
import os
import signal
import socket
import tempfile
import threading
from collections.abc import Callable
from pathlib import Path

from motionweb.flows.app.api import create_app
from motionweb.flows.app.client import remove_discovery, write_discovery
from motionweb.flows.app.engine import Engine
from motionweb.flows.app.recorder import PrefectServer, Recorder
from motionweb.flows.config import Config


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def check_host(host: str, token: str | None) -> None:
    """ValueError unless ``host`` is loopback or a token is given (design §12)."""
    if not is_loopback(host) and not token:
        raise ValueError(f"--host {host} is reachable from other machines: give --token SECRET "
                         "(every request must then carry it)")
    if token is not None and len(token) < 16:
        raise ValueError("--token must be at least 16 characters")


def bind(host: str, port: int) -> socket.socket:
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except OSError as exc:
        sock.close()
        raise ValueError(f"cannot listen on {host}:{port}: {exc.strerror}") from None
    sock.listen(128)
    sock.set_inheritable(True)
    return sock


class Service:
    """The running service (see the module docstring): :meth:`run` blocks until :meth:`stop`
    (or Ctrl-C / SIGTERM). ValueError from the constructor for a bad host, token or port."""

    def __init__(self, cfg: Config, host: str = "127.0.0.1", port: int = 8765, token: str | None = None,
                 record: bool = True, warm: bool = True):
        import uvicorn

        check_host(host, token)
        self.cfg, self.token = cfg, token
        self.sock = bind(host, port)
        self.port = self.sock.getsockname()[1]
        self.url = f"http://{f'[{host}]' if ':' in host else host}:{self.port}"
        self.prefect = self.recorder = None
        if record:
            self.prefect = PrefectServer(Path(tempfile.gettempdir()) / f"motionweb-app-prefect-{os.getpid()}.log")
            self.prefect.start()
            self.recorder = Recorder(self.prefect)
        self.engine = Engine(cfg, on_query=self.recorder.record if self.recorder else None, warm=warm)
        try:
            self.engine.current()  # open the generation now (the warm-up runs behind)
        except ValueError as exc:
            logging.getLogger("motionweb.app").warning("%s; serving anyway, waiting for a commit", exc)
        self.server = _quiet_server()(uvicorn.Config(create_app(self.engine, token), log_level="warning",
                                                    timeout_graceful_shutdown=5, limit_concurrency=256))
        self.info = {"url": self.url, "host": host, "port": self.port, "token": token, "pid": os.getpid(),
                     "prefect": self.prefect.url if self.prefect else None}

    def run(self) -> None:
        """Serve until :meth:`stop`, SIGINT or SIGTERM; then remove the discovery file, end the
        search workers and stop a Prefect server of our own."""
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                signal.signal(sig, lambda *_: self.stop())
        write_discovery(self.cfg.store.path, self.info)
        try:
            self.server.run(sockets=[self.sock])
        finally:
            try:
                remove_discovery(self.cfg.store.path, os.getpid())
                self.engine.close()
                if self.recorder:
                    self.recorder.close()
            finally:
                if self.prefect:
                    self.prefect.stop()
                self.sock.close()

    def stop(self) -> None:
        self.server.should_exit = True


def _quiet_server():
    """A uvicorn server that leaves signals to :class:`Service` (uvicorn re-raises SIGTERM after
    its shutdown, which would skip the service's own cleanup)."""
    import uvicorn

    class Server(uvicorn.Server):
        @contextlib.contextmanager
        def capture_signals(self):
            yield

    return Server


def serve(cfg: Config, host: str = "127.0.0.1", port: int = 8765, token: str | None = None, record: bool = True,
          on_ready: Callable[[str], None] | None = None) -> None:
    """Serve ``cfg``'s store until interrupted; ``on_ready(text)`` says where, once listening."""
    svc = Service(cfg, host, port, token, record)
    if on_ready:
        ui = f"  (Prefect UI {svc.prefect.url[:-4]})" if svc.prefect else ""
        on_ready(svc.url + ("/?token=TOKEN" if token else "/") + ui)
    svc.run()
