"""The service's own settings (the config's ``app`` section): its search cache and the bounds of its
editing sessions.

Defaults live here only (``configs/default.yaml`` lists them; a test holds the two equal). The
session routes (:mod:`motionweb.flows.app.sessions`) and their worker
(:mod:`motionweb.flows.app.session_worker`) read them from ``Config.app``.
"""

from __future__ import annotations

from motionweb.store.params import Params
from pydantic import Field


class AppParams(Params):
    """``motionweb app``'s memory bounds: its search workers' cache (design §5) and its retime
    sessions (design §8, §10; MPS06 §3: a clip's polygons are prepared once per physics and reused
    for every timing)."""

    #: MiB of packed walk graphs each search worker keeps in memory, least recently used dropped
    #: first (the primary and its standby each hold up to this; design §5). 256: with the graph
    #: files below, a graph not in memory costs ~3 ms; on the 381k-frame store the service then
    #: peaks under 2 GB (512: 2.1 GB) at the same latency (bench/app_scale.py)
    cache_mb: float = Field(256.0, gt=0)
    #: GiB of packed walk graphs the search workers keep in files, shared between them and across
    #: runs (``store/filecache.py``: a search that reaches a graph no worker holds reads it back in
    #: ~2 ms instead of reading and packing its webs in ~46 ms); 0: none
    graph_files_gb: float = Field(4.0, ge=0)
    #: their folder, on a local disk (None: $MOTIONWEB_CACHE_DIR/graphs, else
    #: $XDG_CACHE_HOME/motionweb/graphs, else ~/.cache/motionweb/graphs); content-keyed, so
    #: shared by every store and generation and safe to delete at any time
    graph_files_dir: str | None = None
    #: prepared retime plans (one per clip × physics) the session worker keeps, at most
    session_plans: int = Field(8, ge=1, le=256)
    #: and their total size (bytes, numpy arrays counted), at most; the least recently used go first
    session_bytes: int = Field(512 * 1024 * 1024, ge=1024 * 1024)
    #: sessions the service remembers (their clip, physics and last result), at most
    sessions: int = Field(64, ge=1, le=4096)
    #: longest clip a session prepares (seconds): preparing costs O(frames)
    session_max_clip_s: float = Field(60.0, gt=0)
    #: longest output a timing edit may ask for (seconds)
    session_max_duration_s: float = Field(120.0, gt=0)
    #: keytimes per edit, and per-limb mass or weight factors per session, at most
    session_max_keytimes: int = Field(64, ge=0)
    session_max_factors: int = Field(64, ge=0)
    #: uploaded clips (POST /api/uploads, BVH or ASF+AMC): largest request (bytes), how many are
    #: kept in memory (content-addressed, least recently used out) and for how long (seconds)
    upload_bytes: int = Field(16 * 1024 * 1024, ge=64 * 1024, le=1024 * 1024 * 1024)
    uploads: int = Field(32, ge=1, le=1024)
    upload_ttl_s: float = Field(3600.0, gt=0)
    #: MiB the kept uploads may hold in all: their motions and, for one searched as a query (KG04
    #: §3.3), its features and its webs against the indexed clips (built on demand, kept per
    #: generation); the least recently used upload goes first (the newest is kept even alone over it)
    upload_mb: float = Field(256.0, gt=0)


def graph_files(app: AppParams) -> tuple[str, int] | None:
    """(folder, bytes) of the file cache of packed walk graphs (``graph_files_dir`` or
    ``store.filecache.default_folder()``, ``graph_files_gb``), None when it is off: what the
    service's search workers and ``motionweb search`` open (``store.filecache.FileCache``)."""
    if app.graph_files_gb <= 0:
        return None
    from motionweb.store.filecache import default_folder

    return app.graph_files_dir or str(default_folder()), int(app.graph_files_gb * 2**30)
