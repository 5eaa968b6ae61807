"""The service's search work in a child process, so a crash in it cannot take the service down.

The searches' compiled kernels (numba) run in a **worker process** that holds the webs the
searches touch: a web is read from the store when a search first reaches a clip it touches, and
each clip's webs are packed into its walk graph (as :class:`~motionweb.tasks.search.MatchSearch`
packs them); webs and graphs are kept in one LRU bounded by bytes (``app.cache_mb``, shared by
the worker's scopes and generations), so the worker's memory follows what queries touch, not the
size of the library, and opening a generation reads no web (design §5). The service (the parent: HTTP, catalog, poses, downloads, drawing) sends it one
:class:`SearchJob` at a time over a socket pair and gets back the match graph and ε; a result's
registration (KG04 §4.1, compiled DTW kernels too) is computed there as well. One search
at a time, as before (one :class:`MatchSearch` per scope shares its work buffers, and its kernels
hold the GIL): requests that arrive meanwhile wait their turn in the parent.

If the worker dies (a segfault, an abort, a kill), the search it was running — the only one in
it, so the culprit is known — fails with :class:`WorkerCrashed` (the API answers HTTP 500 naming
the query and the signal), and :class:`SearchWorkers` puts the **standby** in its place: a second
worker started in advance and warmed with the same generation, so the next request is answered at
once; a new standby is then started and warmed in the background. Requests that arrive during the
switch wait for it. Without a ready standby (two crashes in a row faster than a warm-up) the next
request waits for a fresh worker's start (imports, ~1-2 s) and reads the webs it needs.

Memory: the primary and the standby each hold at most ``app.cache_mb`` of webs and graphs (the
standby those of the searches it rehearses). With the file cache of graphs on (``app.graph_files_gb``,
the default), a graph lives in its file, mapped (``store.filecache.FileCache.open_mapped``): a walk
reads the pages of the rows it walks, and they leave the worker's resident memory when the search
asks for its next graph and after each request (``FileCache.release``), staying in the page cache; a new generation is opened in a new worker while
the old one keeps serving, then swapped in.

Test hook (off by default): with ``MOTIONWEB_TEST_CRASH_CLIP=NAME`` in the service's environment,
a worker that gets a search of the clip ``NAME`` (corpus path or stem) sends itself SIGSEGV after
the request's checks; ``NAME:abort`` calls :func:`os.abort` instead (SIGABRT); ``NAME:register``
sends SIGSEGV when registering a result whose query is of ``NAME``; several are separated by commas.

Run as ``python -m motionweb.flows.app.worker FD STORE_URL CACHE_BYTES`` by :class:`Worker` only.
"""

from __future__ import annotations

import logging
import os
import queue
import signal
import socket
import subprocess
import sys
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from multiprocessing.connection import Connection
from typing import Any

CRASH_ENV = "MOTIONWEB_TEST_CRASH_CLIP"
#: generations a worker keeps open (the current one and the one before, during a switch)
KEEP_GENERATIONS = 2
#: kinds of search (scope × ε rule) a standby rehearses, at most
KEEP_EXAMPLES = 32
#: glibc's ``M_MMAP_THRESHOLD`` in a worker process, bytes (see :class:`Worker`)
MMAP_THRESHOLD = 256 * 1024
log = logging.getLogger("motionweb.app")


@dataclass(frozen=True)
class SearchJob:
    """One search for the worker: the generation and scope (a category, or ``None`` for every
    chunk), the query segment at the web rate, the search section, and ε given as a threshold, as
    a quantile of the scope's web values, or neither (the default rule: a multiple of the query's
    nearest match)."""

    generation: str
    category: str | None
    segment: Any  # motionweb.tasks.matchgraph.Segment
    params: dict[str, Any]
    threshold: float | None = None
    quantile: float | None = None
    #: a query clip from outside the index (an upload, KG04 §3.3): its web-source name and its webs
    #: (``tasks/query_clip.query_clip_webs``), searched with every category's webs
    query: tuple[str, dict[str, Any]] | None = None

    def kind(self) -> tuple:
        """What a standby rehearses once: the scope and the ε rule (a quantile per value)."""
        rule = "threshold" if self.threshold is not None else self.quantile if self.quantile is not None else "default"
        return self.category, rule


class WorkerCrashed(RuntimeError):
    """The worker died while it ran a job (``how``: e.g. "SIGSEGV", "exit code 1")."""

    def __init__(self, how: str):
        super().__init__(f"the search worker died ({how})")
        self.how = how


def describe_exit(code: int | None) -> str:
    if code is None:
        return "no exit code"
    if code < 0:
        try:
            return signal.Signals(-code).name
        except ValueError:
            return f"signal {-code}"
    return f"exit code {code}"


# ---------------------------------------------------------------------------------- the child
@dataclass
class _Scope:
    webs: Any  # StoreWebs
    search: Any  # MatchSearch
    quantiles: dict[float, float] = field(default_factory=dict)


class _State:
    """What a worker holds: per open generation, its scopes' webs and searches, and one cache of
    webs and walk graphs bounded by ``cache_bytes`` (None: no bound) that they all share."""

    def __init__(self, url: str, cache_bytes: int | None = None, files: tuple[str, int] | None = None):
        from motionweb.store.cache import LRU
        from motionweb.store.filecache import FileCache

        self.url = url
        self.cache = LRU(max_bytes=cache_bytes)
        #: packed walk graphs kept in files (``app.graph_files_gb``), shared with the other worker
        self.files = FileCache(*files) if files is not None else None
        #: per open generation: (generation, its indexed config, its scopes, its store)
        self.gens: OrderedDict[str, tuple[Any, Any, dict[str | None, _Scope], Any]] = OrderedDict()

    def generation(self, gen_id: str) -> tuple[Any, Any, dict[str | None, _Scope], Any]:
        """(generation, its indexed config, its scopes, its store), opened once."""
        from motionweb.store.generations import load_generation
        from motionweb.store.zarr_store import MotionStore

        if gen_id not in self.gens:
            store = MotionStore(self.url, read_only=True)
            self._keep(load_generation(store, gen_id, lean=True), store)
        self.gens.move_to_end(gen_id)
        return self.gens[gen_id]

    def _keep(self, gen: Any, store: Any) -> None:
        """Hold ``gen`` opened on ``store`` (the last :data:`KEEP_GENERATIONS`). One store per
        generation, shared by its scopes and registrations: a store holds the index of every
        web's bytes once read (O(webs of the store)), so one per scope would hold it once per
        category searched."""
        from motionweb.flows.query import indexed_config

        self.gens[gen.id] = (gen, indexed_config(gen), {}, store)
        while len(self.gens) > KEEP_GENERATIONS:
            self.gens.popitem(last=False)

    def open_current(self) -> str | None:
        """Open the store's current generation before the service names it (its manifest parsed
        while the service parses its own, on the other core); its id, None when there is none
        (never indexed, or damaged: the service says so)."""
        from motionweb.store.generations import current_generation
        from motionweb.store.zarr_store import MotionStore

        store = MotionStore(self.url, read_only=True)
        gen = current_generation(store, lean=True)
        if gen is None:
            return None
        if gen.id not in self.gens:
            self._keep(gen, store)
        return gen.id

    def scope(self, gen_id: str, category: str | None) -> _Scope:
        from motionweb.store.webs import StoreWebs
        from motionweb.tasks.search import MatchSearch, SearchParams

        gen, gen_cfg, scopes, store = self.generation(gen_id)
        sc = scopes.get(category)
        if sc is None:
            webs = StoreWebs(store, gen, category, self.cache, keep_webs=False)  # the cache keeps graphs
            sc = scopes[category] = _Scope(webs, MatchSearch(webs, SearchParams(), gen_cfg.matchweb,
                                                             self.cache, (gen_id, category), self.files))
        return sc

    def warm(self, gen_id: str, category: str | None) -> int:
        """Open the scope: index its web records by clip (O(webs of the generation)), reading no
        web, and take in a shard of the store (the one its first web is in when the generation
        records it, else all: their keys, once per store); the number of clips.
        Searches read the webs they reach."""
        sc = self.scope(gen_id, category)
        if len(sc.webs.table):
            rec = sc.webs.table[0]
            self.generation(gen_id)[3].web_shard(rec["key"], rec.get("shard"))
        return len(sc.webs)

    def stats(self) -> dict[str, Any]:
        """The cache's entries, bytes and bound, and the webs read from the store so far."""
        reads = sum(sc.webs.reads for _, _, scopes, _ in self.gens.values() for sc in scopes.values())
        files = self.files.stats() if self.files is not None else None
        return {**self.cache.stats(), "webs_read": reads, "graph_files": files}

    def search(self, job: SearchJob) -> tuple[Any, float | None]:
        from motionweb.tasks.ranking import search_query
        from motionweb.tasks.search import SearchParams

        if job.query is not None:
            return self.search_file(job)
        sc = self.scope(job.generation, job.category)
        params = SearchParams.model_validate(job.params)
        sc.search.cfg = params
        sc.search.check(job.segment)
        _test_crash(job.segment.clip)

        def quantile_value(q: float) -> float:  # a scope's quantiles, computed once
            if q not in sc.quantiles:
                sc.quantiles[q] = sc.search.quantile(q, stream=True)  # one pass, not kept (or its file)
            return sc.quantiles[q]

        return search_query(sc.search, job.segment, job.threshold, job.quantile, quantile_value)

    def search_file(self, job: SearchJob) -> tuple[Any, float | None]:
        """A search whose query clip is from outside the index (``job.query``: its name and webs),
        as the query flow runs ``search --query-file`` (``flows/query.search_task``): the index's
        webs of every category (the shared cache's) plus the clip's, ε from them all. The walk
        graphs of the clips it reaches are packed with its webs, kept under its own key."""
        from motionweb.tasks.query_clip import WithQueryClip
        from motionweb.tasks.ranking import search_query
        from motionweb.tasks.search import MatchSearch, SearchParams

        name, webs = job.query
        _, gen_cfg, _, _ = self.generation(job.generation)
        source = WithQueryClip(self.scope(job.generation, None).webs, name, webs)
        ms = MatchSearch(source, SearchParams.model_validate(job.params), gen_cfg.matchweb, self.cache,
                         (job.generation, "query", name))  # the name holds the content id
        ms.check(job.segment)
        _test_crash(job.segment.clip)
        return search_query(ms, job.segment, job.threshold, job.quantile)

    def query_webs(self, gen_id: str, name: str, motion: Any) -> tuple[dict[str, Any], dict[str, Any]]:
        """The record (its features under ``flows/query.FILE_FEATURES``) and webs of ``motion``, a
        clip from outside the index named ``name``, against generation ``gen_id``'s clips of its
        skeleton: ``flows/query.prepare_file_query`` (``search --query-file``'s code path)."""
        from motionweb.flows.commands.requests import QueryRequest
        from motionweb.flows.query import prepare_file_query

        gen, gen_cfg, _, store = self.generation(gen_id)
        rate = max(float(r) for r in gen_cfg.features.rates)
        # the window is checked by the service; this one only names the clip (the webs span it
        # all): its first frame at the web rate, inside any clip whatever its length
        q = prepare_file_query(store, gen, gen_cfg, rate, QueryRequest(clip=name, start=0.0, end=1.0 / rate),
                               motion)
        return q.record, q.webs.webs

    def register(self, gen_id: str, graph: Any, extra: dict[str, Any] | None = None) -> Any:
        """The registration of a search's match graph (KG04 §4.1); ``extra``: records of clips
        from outside the index (a query upload's, with its features)."""
        from motionweb.flows.query import register_graph

        gen, gen_cfg, _, store = self.generation(gen_id)
        _test_crash(graph.nodes[0].segment.clip, "register")
        return register_graph(store, gen, gen_cfg, graph,
                              {**{c["path"]: c for c in gen.clips}, **(extra or {})})


def _test_crash(clip: str, stage: str = "search") -> None:
    """The test hook (see the module docstring): crash on a search of ``$MOTIONWEB_TEST_CRASH_CLIP``."""
    for target in os.environ.get(CRASH_ENV, "").split(","):
        name, _, how = target.strip().partition(":")
        if (how == "register") != (stage == "register"):
            continue
        if name and (clip == name or clip.rsplit("/", 1)[-1].rsplit(".", 1)[0] == name):
            if how == "abort":
                os.abort()
            os.kill(os.getpid(), signal.SIGSEGV)


def serve(fd: int, name: str, handlers: dict[str, Callable[[Any], Any]]) -> None:
    """A worker process's loop, for the search worker and the session worker alike: (kind,
    payload) in, ("ok", ``handlers[kind](payload)``) / ("value", message: a ValueError, the
    request's fault) / ("error", type name: anything else, logged) out; ("ping", _) answers the
    pid. Sends ("ready", pid) first; ends on EOF (the service closed or died). Crashes leave a
    Python traceback in the service's log (faulthandler); Ctrl-C is the service's to handle."""
    import faulthandler

    faulthandler.enable()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    conn = Connection(fd)
    conn.send(("ready", os.getpid()))
    while True:
        try:
            kind, payload = conn.recv()
        except (EOFError, OSError):
            return
        try:
            if kind == "ping":
                out = ("ok", os.getpid())
            elif kind in handlers:
                out = ("ok", handlers[kind](payload))
            else:
                out = ("error", f"unknown request {kind!r}")
        except ValueError as exc:
            out = ("value", str(exc))
        except Exception as exc:
            logging.getLogger("motionweb.app").exception("%s: %s failed", name, kind)
            out = ("error", type(exc).__name__)
        try:
            conn.send(out)
        except (EOFError, OSError):
            return


def raise_open_files(most: int = 1 << 16) -> int:
    """Raise this process's soft limit on open files to its hard limit (at most ``most``) and
    return the soft limit: each graph file a worker keeps mapped holds a descriptor
    (``store.filecache.mapping_slots``), and a default soft limit of 1024 would cap them low."""
    import resource

    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    want = most if hard == resource.RLIM_INFINITY else min(int(hard), most)
    if soft != resource.RLIM_INFINITY and soft < want:
        try:
            resource.setrlimit(resource.RLIMIT_NOFILE, (want, hard))
            soft = want
        except (ValueError, OSError):  # not allowed here: keep the limit, the mappings follow it
            pass
    return int(soft)


def child_main(fd: int, url: str, cache_bytes: int | None = None, files: tuple[str, int] | None = None) -> None:
    """The search worker: ("search", job) / ("warm", (gen, category)) / ("register", (gen,
    graph)) / ("open", _) / ("stats", _) through :func:`serve`; ``cache_bytes`` bounds its cache of webs and
    graphs, ``files`` (folder, bytes) its file cache of graphs."""
    from motionweb.tasks.search import MatchSearch  # noqa: F401  (import the heavy stack before "ready")

    raise_open_files()  # before the file cache sizes its mappings by the limit
    state = _State(url, cache_bytes, files)

    def then_release(handler: Callable[[Any], Any]) -> Callable[[Any], Any]:
        """``handler``, after which the pages of the graphs it walked leave the worker's resident
        memory (``FileCache.release``; they stay in the page cache) and the mappings of graph
        files another process removed are dropped."""
        def run(payload: Any) -> Any:
            try:
                return handler(payload)
            finally:
                if state.files is not None:
                    state.files.release(sweep=True)
        return run

    serve(fd, "search worker", {"search": then_release(state.search), "warm": lambda p: state.warm(*p),
                                "register": then_release(lambda p: state.register(*p)),
                                "query_webs": then_release(lambda p: state.query_webs(*p)),
                                "stats": lambda _: state.stats(), "open": lambda _: state.open_current()})


# --------------------------------------------------------------------------------- the parent
class Worker:
    """One worker process and its end of the socket pair; :meth:`call` is one request at a time.
    ``cache_bytes``: the bound of its cache of webs and graphs (None: none)."""

    def __init__(self, *args: str, module: str = "motionweb.flows.app.worker"):
        """Start ``python -m module FD *args`` (this module's loop, given the store URL; or another
        worker's, e.g. :mod:`motionweb.flows.app.session_worker`)."""
        mine, theirs = socket.socketpair()
        # glibc's malloc: a fixed mmap threshold, so that arrays of 256 kB and more (decompressed
        # chunks, walk graphs packed and evicted) go back to the system when freed; its default
        # raises the threshold after such a free and then serves them from a heap that a day of
        # searches fragments (381k-frame store: 1.26 GB resident for 0.26 GB of cache, 0.64 GB
        # with the threshold fixed). Ignored by other C libraries.
        env = {"MALLOC_MMAP_THRESHOLD_": str(MMAP_THRESHOLD), **os.environ, "PYTHONUNBUFFERED": "1"}
        self.proc = subprocess.Popen([sys.executable, "-m", module, str(theirs.fileno()), *args],
                                     pass_fds=[theirs.fileno()], stdin=subprocess.DEVNULL,
                                     stdout=subprocess.DEVNULL, env=env, close_fds=True)
        theirs.close()
        self.conn = Connection(mine.detach())
        self.lock = threading.Lock()
        self.ready = self.closing = self.rehearsed = False
        self.warm: set[tuple[str, str | None]] = set()
        self.lessons: queue.Queue[SearchJob | None] = queue.Queue()  # searches a standby rehearses
        self.started = time.monotonic()

    @property
    def pid(self) -> int:
        return self.proc.pid

    def alive(self) -> bool:
        return self.proc.poll() is None

    def _died(self) -> WorkerCrashed:
        try:
            code = self.proc.wait(5)
        except subprocess.TimeoutExpired:  # the pipe broke but the process lives on: end it
            self.proc.kill()
            code = self.proc.wait()
        return WorkerCrashed(describe_exit(code))

    def call(self, kind: str, payload: Any) -> Any:
        """Send one request and wait for its answer. ValueError with the worker's message for a bad
        request, RuntimeError for another failure, :class:`WorkerCrashed` if the worker died."""
        with self.lock:
            try:
                if not self.ready:
                    tag, _ = self.conn.recv()
                    if tag != "ready":
                        raise EOFError
                    self.ready = True
                self.conn.send((kind, payload))
                tag, out = self.conn.recv()
            except (EOFError, OSError):
                raise self._died() from None
        if tag == "ok":
            return out
        if tag == "value":
            raise ValueError(out)
        raise RuntimeError(f"the search worker failed ({out}); see the service's log")

    def close(self, timeout: float = 5.0) -> None:
        """End the worker (SIGTERM: it holds nothing to save; SIGKILL after ``timeout`` s), then
        close its socket once no call uses it."""
        self.closing = True
        self.lessons.put(None)
        if self.proc.poll() is None:
            self.proc.terminate()
        try:
            self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        if self.lock.acquire(timeout=timeout):  # a call in flight ends with EOF now
            try:
                self.conn.close()
            finally:
                self.lock.release()


class SearchWorkers:
    """The supervised workers of one store (see the module docstring): :meth:`search` runs a job
    on the primary; :meth:`prepare` warms a generation; :meth:`close` ends them all.

    ``standby``: keep a second warmed worker ready to take over after a crash; ``cache_bytes``:
    each worker's bound on the webs and graphs it keeps (None: none)."""

    def __init__(self, url: str, standby: bool = True, cache_bytes: int | None = None,
                 files: tuple[str, int] | None = None):
        self.url, self.standby, self.cache_bytes, self.files = url, standby, cache_bytes, files
        self._stats: dict[str, Any] | None = None  # the primary's cache, as last asked
        self._call = threading.Lock()  # one job at a time on the primary
        self._state = threading.Lock()  # guards the fields below
        self._primary: Worker | None = None
        self._spare: Worker | None = None
        self._scopes: tuple[str, list[str | None]] | None = None  # the generation to warm and its scopes
        self._closed = False
        #: one answered search per kind (scope × ε rule): a standby runs each once, so that the
        #: first search after a crash finds its code compiled and its ε quantiles computed
        self._examples: dict[tuple, SearchJob] = {}
        self.crashes = 0
        self.last_crash: str | None = None

    # -------------------------------------------------------------- workers
    def _new_worker(self) -> Worker:
        files = self.files or ("", 0)
        return Worker(self.url, str(self.cache_bytes or 0), files[0], str(files[1]))

    def _warm(self, w: Worker, gen_id: str, scopes: list[str | None]) -> None:
        for cat in scopes:
            if (gen_id, cat) in w.warm:
                continue
            w.call("warm", (gen_id, cat))
            w.warm.add((gen_id, cat))

    def _start_spare(self) -> None:
        """Start a standby and warm it in the background (when there is none)."""
        with self._state:
            if not self.standby or self._closed or (self._spare is not None and self._spare.alive()):
                return
            w = self._spare = self._new_worker()
            scopes = self._scopes

        def warm() -> None:
            try:
                w.call("ping", None)  # its imports done
                if scopes is not None:
                    self._warm(w, *scopes)
                self._rehearse(w, list(self._examples.values()))
                w.rehearsed = True
                while not w.closing:
                    job = w.lessons.get()
                    try:
                        if job is not None:
                            self._rehearse(w, [job])
                    finally:
                        w.lessons.task_done()
            except (WorkerCrashed, RuntimeError, OSError) as exc:
                if not w.closing:
                    log.warning("search worker standby: %s", exc)

        threading.Thread(target=warm, name="search-standby", daemon=True).start()

    def _rehearse(self, w: Worker, jobs: list[SearchJob]) -> None:
        """Run ``jobs`` on ``w`` for their side effects (compiled code loaded, webs read, ε cached)."""
        want = self._scopes[0] if self._scopes is not None else None
        for job in jobs:
            try:
                w.call("search", job if want is None else replace(job, generation=want))
            except ValueError:  # e.g. the clip is gone from a new generation
                pass

    def _learn(self, job: SearchJob) -> None:
        """Remember ``job`` as its kind's example (and have the standby rehearse it)."""
        with self._state:
            if job.kind() in self._examples or len(self._examples) >= KEEP_EXAMPLES:
                return
            self._examples[job.kind()] = job
            spare = self._spare
        if spare is not None:
            spare.lessons.put(job)

    def _primary_worker(self, spare: bool = True) -> Worker:
        """The primary (under ``_call``): the standby promoted, or a new worker (then a new
        standby is started, unless not ``spare``)."""
        with self._state:
            if self._closed:
                raise RuntimeError("the service is stopping")
            if self._primary is None or not self._primary.alive():
                spare, self._spare = self._spare, None
                self._primary = spare if spare is not None and spare.alive() else self._new_worker()
                promoted = spare is self._primary
            else:
                return self._primary
        log.info("search worker %d %s", self._primary.pid, "promoted from standby" if promoted else "started")
        if spare:
            self._start_spare()
        return self._primary

    # -------------------------------------------------------------- requests
    def search(self, job: SearchJob) -> tuple[Any, float]:
        """(match graph, ε) of ``job``, computed by the primary worker. ValueError for a bad
        request (the CLI's messages), :class:`WorkerCrashed` if the worker died running it (the
        next call gets the standby)."""
        out = self._run("search", job, f"a search of {job.segment.clip} [{job.segment.start}, {job.segment.end}]")
        if job.query is None:  # an upload's search is not rehearsed (its webs are the request's)
            self._learn(job)
        return out

    def register(self, gen_id: str, graph: Any, extra: dict[str, Any] | None = None) -> Any:
        """The :class:`~motionweb.tasks.register.Registration` of ``graph`` (a search's answer on
        generation ``gen_id``; ``extra``: records of clips from outside the index), computed by the
        primary worker; errors as :meth:`search`."""
        q = graph.nodes[0].segment
        return self._run("register", (gen_id, graph, extra), f"a registration of {q.clip} [{q.start}, {q.end}]")

    def query_webs(self, gen_id: str, name: str, motion: Any) -> tuple[dict[str, Any], dict[str, Any]]:
        """The record and webs of a clip from outside the index (:meth:`_State.query_webs`),
        built by the primary worker (compiled kernels: a crash costs the request); errors as
        :meth:`search`."""
        return self._run("query_webs", (gen_id, name, motion), f"the webs of the query clip {name}")

    def _run(self, kind: str, payload: Any, what: str) -> Any:
        with self._call:
            w = self._primary_worker()
            try:
                return w.call(kind, payload)
            except WorkerCrashed as exc:
                with self._state:
                    self.crashes += 1
                    self.last_crash = exc.how
                    if self._primary is w:
                        self._primary = None
                log.error("search worker %d died (%s) running %s", w.pid, exc.how, what)
                threading.Thread(target=self._after_crash, name="search-restart", daemon=True).start()
                raise

    def _after_crash(self) -> None:
        """Promote the standby now (so the next request finds it in place) and start a new one."""
        with self._call:
            if not self._closed:
                self._primary_worker()

    def start(self) -> None:
        """Start the primary and have it open the store's current generation now, while the
        service opens its own (:meth:`prepare` then finds it open). Errors are logged: the
        requests after it start a worker again and say what is wrong."""
        try:
            with self._call:
                if self._primary is None:
                    self._primary_worker(spare=False).call("open", None)
        except (WorkerCrashed, RuntimeError, ValueError, OSError) as exc:
            log.warning("search worker: opening the current generation: %s", exc)

    def prepare(self, gen_id: str, scopes: list[str | None]) -> None:
        """Open ``gen_id``'s ``scopes`` (category names; ``None`` for all categories) for searching
        (no web is read: searches read what they reach). The first generation is opened in the
        primary, scope by scope between searches; a later one in a new worker while the primary
        keeps serving (which also rehearses the searches seen so far), which then replaces it.
        The standby is then replaced by one opened for ``gen_id``."""
        with self._state:
            first = self._scopes is None
            self._scopes = (gen_id, list(scopes))
        if first:
            for cat in scopes:
                with self._call:
                    w = self._primary_worker(spare=False)  # the standby after the warm-up
                    try:
                        self._warm(w, gen_id, [cat])
                    except (WorkerCrashed, RuntimeError) as exc:
                        log.warning("search worker: warming %s: %s", cat, exc)
            self._start_spare()
            return
        fresh = self._new_worker()
        try:
            self._warm(fresh, gen_id, scopes)
            self._rehearse(fresh, list(self._examples.values()))
        except (WorkerCrashed, RuntimeError, ValueError) as exc:
            log.warning("search worker: warming generation %s: %s", gen_id, exc)
            fresh.close(0)
            return
        with self._call, self._state:
            old, self._primary = self._primary, fresh
            spare, self._spare = self._spare, None
        for w in (old, spare):
            if w is not None:
                w.close()
        self._start_spare()

    def info(self) -> dict[str, Any]:
        with self._state:
            p, s = self._primary, self._spare
            want = self._scopes
            return {"pid": p.pid if p is not None and p.alive() else None, "crashes": self.crashes,
                    "last_crash": self.last_crash,
                    "standby": s is not None and s.alive() and s.rehearsed and s.lessons.unfinished_tasks == 0
                    and (want is None or all((want[0], c) in s.warm for c in want[1]))}

    def cache_stats(self, wait: float = 0.2) -> dict[str, Any] | None:
        """The primary worker's cache (:meth:`_State.stats`), asked when it is free within
        ``wait`` seconds, else as last asked (None: never)."""
        if self._call.acquire(timeout=wait):
            try:
                with self._state:
                    w = self._primary
                if w is not None and w.ready and w.alive():
                    self._stats = w.call("stats", None)
            except (WorkerCrashed, RuntimeError, OSError):
                pass
            finally:
                self._call.release()
        return self._stats

    def pids(self) -> list[int]:
        with self._state:
            return [w.pid for w in (self._primary, self._spare) if w is not None and w.alive()]

    def close(self) -> None:
        """End every worker (waits for a running search up to 5 s, then kills)."""
        with self._state:
            self._closed = True
            workers, self._primary, self._spare = [self._primary, self._spare], None, None
        for w in workers:
            if w is not None:
                w.close()


if __name__ == "__main__":
    child_main(int(sys.argv[1]), sys.argv[2], int(sys.argv[3]) or None,
               (sys.argv[4], int(sys.argv[5])) if len(sys.argv) > 5 and int(sys.argv[5]) > 0 else None)
