"""Finding a running service for a store, and sending it the CLI's queries.

A running ``motionweb app`` writes a discovery file ``<dir>/<sha256(store url)[:16]>.json``
(``dir`` = ``$MOTIONWEB_APP_DIR``, default ``~/.cache/motionweb/app``, mode 0700; the file mode
0600, since it holds the token) with its URL, token and process id, and removes it when it stops.
``motionweb search``, ``synthesize`` and ``blend`` read it and, when the service answers, send
the query there and write the same files a local run would. This module imports only the
standard library and YAML, so a forwarded command does not pay for importing the stages (numpy,
numba, scipy, zarr, matplotlib, Prefect).
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import re
import urllib.error
import urllib.request
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from motionweb.flows.paths import resolve_path

if TYPE_CHECKING:
    from motionweb.flows.commands.requests import QueryRequest

ENV_DIR = "MOTIONWEB_APP_DIR"


def discovery_dir() -> Path:
    return Path(os.environ.get(ENV_DIR) or Path.home() / ".cache" / "motionweb" / "app")


def discovery_file(store_url: str) -> Path:
    return discovery_dir() / f"{hashlib.sha256(store_url.encode()).hexdigest()[:16]}.json"


def write_discovery(store_url: str, info: dict[str, Any]) -> Path:
    """Write the discovery file atomically, readable by its owner only."""
    d = discovery_dir()
    d.mkdir(parents=True, exist_ok=True)
    os.chmod(d, 0o700)
    path = discovery_file(store_url)
    tmp = path.with_suffix(f".{os.getpid()}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as fh:
        json.dump({"store": store_url, **info}, fh)
    os.replace(tmp, path)
    return path


def remove_discovery(store_url: str, pid: int) -> None:
    """Remove the discovery file if it is still this process's."""
    path = discovery_file(store_url)
    try:
        if json.loads(path.read_text()).get("pid") == pid:
            path.unlink()
    except (OSError, ValueError):
        pass


@dataclass
class Service:
    url: str
    token: str | None

    def call(self, method: str, path: str, body: dict | None = None, timeout: float = 600.0) -> tuple[int, bytes]:
        """(status, body bytes) of one request; OSError when the service does not answer."""
        data = None if body is None else json.dumps(body).encode()
        req = urllib.request.Request(self.url + path, data=data, method=method)
        if data is not None:
            req.add_header("Content-Type", "application/json")
        if self.token:
            req.add_header("Authorization", f"Bearer {self.token}")
        try:
            with urllib.request.urlopen(req, timeout=timeout) as r:
                return r.status, r.read()
        except urllib.error.HTTPError as exc:
            return exc.code, exc.read()


def find_service(store_url: str) -> Service | None:
    """The running service of ``store_url`` (its discovery file, owned by this user and naming a
    live process), or None."""
    path = discovery_file(store_url)
    try:
        st = path.stat()
        if st.st_uid != os.getuid() or st.st_mode & 0o077:
            return None  # not ours, or readable by others: do not trust it
        info = json.loads(path.read_text())
        os.kill(int(info["pid"]), 0)
    except (OSError, ValueError, KeyError, TypeError):
        return None
    if info.get("store") != store_url:
        return None
    return Service(info["url"], info.get("token"))


def raw_config(path: Path | None) -> dict[str, Any] | None:
    """The config file as YAML data, its store and output paths resolved (those of the packaged
    default, ``path`` None, against the working directory, as the config loader does); None when
    it cannot be read as a mapping (the local run then reports the problem)."""
    from importlib import resources

    import yaml

    try:
        if path is None:
            text, base = (resources.files("motionweb.configs") / "default.yaml").read_text(), Path.cwd()
        else:
            text, base = path.read_text(), path.resolve().parent
        data = yaml.safe_load(text) or {}
    except (OSError, yaml.YAMLError):
        return None
    if not isinstance(data, dict) or not isinstance(data.get("store", {}), dict):
        return None
    data["store_path"] = resolve_path((data.get("store") or {}).get("path", "motionweb-store"), base)
    data["output"] = resolve_path(data.get("output", "motionweb-out"), base)
    return data


class ServiceError(Exception):
    """The service refused the query; the message is the CLI's."""


def ask(config: Path | None, data: dict[str, Any], path: str, body: dict[str, Any]) -> tuple[Service, bytes] | None:
    """POST ``body`` to ``path`` of the running service of the store of ``data`` (the config
    ``config`` as :func:`raw_config` read it): (service, the answer), or None when no service
    runs (or it does not answer): then the caller runs locally. :class:`ServiceError` with the
    service's message when it refuses."""
    svc = find_service(data["store_path"])
    if svc is None:
        return None
    try:
        status, payload = svc.call("POST", path, body)
    except OSError:
        return None  # gone since it wrote its file: run locally
    if status != 200:
        try:
            message = json.loads(payload)["error"]
        except (ValueError, KeyError, TypeError):
            message = f"the service answered {status}"
        if status == 400 and message.startswith("search."):
            message = f"{config}: {message}"
        raise ServiceError(message)
    return svc, payload


def forward_search(config: Path, request: QueryRequest) -> dict[str, Any] | None:
    """Send ``motionweb search``'s request (the model the service's ``/api/query`` takes) to the
    running service of the config's store and write its outputs where the local run would
    (``request.out`` or the config's output; exported BVH into ``request.export``). The query
    flow's result with local paths, or None when there is no running service: then the caller
    runs locally."""
    data = raw_config(config)
    if data is None:
        return None
    body = {k: v for k, v in request.wire().items() if v is not None}
    body["search"] = data.get("search") if isinstance(data.get("search"), dict) else None
    got = ask(config, data, "/api/query", body)
    if got is None:
        return None
    svc, payload = got
    out = Path(request.out or data["output"])
    export = Path(request.export) if request.export else None
    with zipfile.ZipFile(io.BytesIO(payload)) as z:
        res = json.loads(z.read("result.json"))
        files = []
        for name in res["files"]:
            top, _, rest = name.partition("/")
            dest = (export if top == "export" else out) / rest
            if top not in ("out", "export") or ".." in Path(rest).parts or (top == "export" and export is None):
                raise ServiceError(f"the service sent an unexpected file {name!r}")
            dest.parent.mkdir(parents=True, exist_ok=True)
            dest.write_bytes(z.read(name))
            files.append(str(dest))
    res["out"], res["files"], res["service"] = str(out), files, svc.url
    return res


def forward_space(config: Path | None, space: str, kind: str, body: dict[str, Any], out: Path
                  ) -> dict[str, Any] | None:
    """Send ``motionweb synthesize`` (``kind`` "synthesize", ``body`` {"target": [...]}) or
    ``blend`` ({"weights": {...}}) to the running service of the config's store and write the
    BVH it makes to ``out``, as the local run would. Its answer (frames, fps, achieved, ...)
    without the BVH text, or None when no service runs (or ``space`` is no hex id: the local
    run names the problem, and the local run writes any output that is not BVH: GLB, FBX)."""
    data = raw_config(config)
    if data is None or not re.fullmatch(r"[0-9a-f]{1,64}", space) or out.suffix.lower() != ".bvh":
        return None
    got = ask(config, data, f"/api/spaces/{space}/{kind}", {**body, "pose": False, "bvh": True})
    if got is None:
        return None
    svc, payload = got
    res = json.loads(payload)
    try:
        out.write_text(res.pop("bvh"))
    except OSError as exc:
        raise ServiceError(str(exc)) from None
    res["service"] = svc.url
    return res
