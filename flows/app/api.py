"""The service's JSON API and page (FastAPI) over an :class:`~motionweb.flows.app.engine.Engine`.

Routes (every one answers JSON errors ``{"error": message}`` with the CLI's messages, never a
traceback: 400 bad request, 401 bad token, 404 unknown clip or result, 409 store not indexed,
413 request too large, 500 a search (or a retime session's work) that crashed its worker
process, with ``"query"``: the request's clip, start, end and options (the session's request);
the service goes on with a standby worker, or a fresh session worker):

    GET  /                                       the page (static/index.html)
    GET  /api/status                             generation, clip and web counts, categories
    GET  /api/catalog?category=&name=&min_s=&max_s=&offset=&limit=
    GET  /api/clips/{id}/pose?rate=              joint positions (metres) for drawing
    GET  /api/clips/{id}/bvh                     the clip as a BVH download (/glb: as GLB)
    POST /api/search                             a search (KG04 §3.3): rows by graph distance, graph
    GET  /api/results/{rid}                      a search's rows and graph again
    GET  /api/results/{rid}/registration         the time-warp curves s_i(u) (KG04 §4.1)
    GET  /api/results/{rid}/nodes/{rank}/pose?registered=   a match's positions, optionally registered
    GET  /api/results/{rid}/nodes/{rank}/bvh?registered=    a match as a BVH download (/glb: as GLB)
    POST /api/query                              what `motionweb search` writes, as a zip
                                                 (result.json, out/..., export/...)
    GET  /api/spaces                             the stored motion spaces (KG04 §4)
    GET  /api/spaces/{sid}                       a space's parameter, examples, sampled cloud
    POST /api/spaces/{sid}/synthesize            {target}: the motion for it (§4.3), how close
    POST /api/spaces/{sid}/blend                 {weights}: the blend of the examples
    GET  /api/retime/status                      the session worker: pid, crashes, plans kept, their bytes
    POST /api/retime/sessions                    {clip, gravity, mass, weight}: a retime session (MPS06),
                                                 its plan prepared once per (clip, physics); the original's poses
    POST /api/retime/sessions/{sid}/edit         {duration, keytimes}: the retimed poses and the plots' data
    GET  /api/retime/sessions/{sid}/bvh          the last retimed motion as a BVH download
    GET  /api/retime/sessions/{sid}/report       the last retiming's report (the CLI's JSON)
    POST /api/warp/sessions                      {clip, reference}: a guided-warp session (HDP07), the
                                                 reference's scores kept; the original's
                                                 and the reference's poses
    POST /api/warp/sessions/{sid}/edit           {duration, keytimes, fast}: the warped poses, the warp curve,
                                                 each flight's ratio
    GET  /api/warp/sessions/{sid}/bvh            the last warp as a BVH download
    POST /api/uploads                            {name, bvh | asf + amc, unit, scale_to_m, fps}: a clip of the
                                                 user's own, parsed by the hardened readers, kept in memory
                                                 (content-addressed, bounded); its id (up-...) names it in sessions
                                                 and as a search's query clip
    GET  /api/uploads/{uid}                      an upload's name, frames, fps, joints, unit, bytes kept
    GET  /api/uploads/{uid}/pose?rate=           its joint positions for drawing (the player)

A search (``/api/search``) may name an upload as its clip: its features and its webs against the
indexed clips are built on demand by the search worker (``search --query-file``'s code path,
``flows/query.prepare_file_query``) and kept with the upload (``app.upload_mb``); its matches
answer as an indexed query's.

Security (design §12): with a token every request must carry it (``Authorization: Bearer``, or
the cookie the page sets after ``/?token=``; compared in constant time); no request names a
filesystem path (clips by index id or corpus name looked up in the generation, downloads built in
memory); bodies are at most :data:`MAX_BODY` bytes (an upload ``app.upload_bytes``), query strings
:data:`MAX_QUERY_STRING`.
"""

from __future__ import annotations

import hmac
import logging
from importlib import resources
from typing import Any

import anyio
from fastapi import FastAPI, Query, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, JSONResponse, Response
from fastapi.staticfiles import StaticFiles
from motionweb.flows.app.engine import MAX_DRAW_FRAMES, Engine, NotFound, NotIndexed, QueryCrashed
from motionweb.flows.app.sessions import (
    EditBody,
    RetimeSessions,
    SessionBody,
    WarpEditBody,
    WarpSessionBody,
    WarpSessions,
)
from motionweb.flows.app.spaces import Spaces
from motionweb.flows.app.uploads import UploadBody
from motionweb.flows.commands.requests import (
    BlendRequest,
    QueryRequest,
    SearchQuery,
    SynthesizeRequest,
    message,
)
from pydantic import Field, ValidationError
from starlette.exceptions import HTTPException as StarletteHTTPException

MAX_BODY = 64 * 1024
MAX_QUERY_STRING = 2048
TOKEN_COOKIE = "motionweb_token"
log = logging.getLogger("motionweb.app")


def static_dir() -> str:
    """The page's files (package data of motionweb.flows.app)."""
    with resources.as_file(resources.files("motionweb.flows.app") / "static") as path:
        return str(path)


class SearchBody(SearchQuery):
    """A search: ``motionweb search``'s request model (``flows/commands/requests.py``), the clip by id or
    corpus name, and ``search``: overrides of the config's search section (the CLI sends its
    config's)."""

    search: dict[str, Any] | None = Field(default=None, max_length=16)


class QueryBody(QueryRequest):
    """``motionweb search`` forwarded (the same model): ``out`` and ``export`` are the client's
    folders, only recorded in matches.json (the service writes nothing where a request says)."""

    search: dict[str, Any] | None = Field(default=None, max_length=16)


class SynthesizeBody(SynthesizeRequest):
    """``motionweb synthesize``'s request (a target parameter, metres, as many values as the
    space's parameter has) and what to answer with."""

    pose: bool = True
    bvh: bool = False


class BlendBody(BlendRequest):
    """``motionweb blend``'s request (weights by example, corpus path or stem, summing to 1) and
    what to answer with."""

    pose: bool = True
    bvh: bool = False


def error(status: int, message: str) -> JSONResponse:
    return JSONResponse({"error": message}, status_code=status)


class Guard:
    """ASGI middleware: the token on every request (when set), bounded bodies and query strings."""

    def __init__(self, app, token: str | None, limits: dict[str, int] | None = None):
        self.app, self.token = app, token
        self.limits = limits or {}  # a larger body limit for some paths (the uploads)

    def authorized(self, scope) -> bool:
        if not self.token:
            return True
        headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope.get("headers", [])}
        given = ""
        auth = headers.get("authorization", "")
        if auth.lower().startswith("bearer "):
            given = auth[7:].strip()
        if not given:
            for part in headers.get("cookie", "").split(";"):
                k, _, v = part.strip().partition("=")
                if k == TOKEN_COOKIE:
                    given = v
        if not given and scope.get("path") == "/":
            from urllib.parse import parse_qs

            given = parse_qs(scope.get("query_string", b"").decode("latin-1")).get("token", [""])[0]
        return hmac.compare_digest(given.encode(), self.token.encode())

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        if len(scope.get("query_string", b"")) > MAX_QUERY_STRING or len(scope.get("path", "")) > 512:
            return await error(414, "request line too long")(scope, receive, send)
        if not self.authorized(scope):
            return await error(401, "missing or wrong token (Authorization: Bearer TOKEN, or open /?token=TOKEN)")(
                scope, receive, send)
        limit = self.limits.get(scope.get("path", ""), MAX_BODY)
        length = dict(scope.get("headers", [])).get(b"content-length")
        if length is not None and (not length.isdigit() or int(length) > limit):
            return await error(413, f"request body larger than {limit} bytes")(scope, receive, send)
        seen = 0

        async def bounded():
            nonlocal seen
            msg = await receive()
            if msg["type"] == "http.request":
                seen += len(msg.get("body", b""))
                if seen > limit:
                    raise TooLarge
            return msg

        try:
            await self.app(scope, bounded, send)
        except TooLarge:
            await error(413, f"request body larger than {limit} bytes")(scope, receive, send)


class TooLarge(Exception):
    pass


def create_app(engine: Engine, token: str | None = None) -> Guard:
    """The FastAPI app of ``engine`` behind its :class:`Guard` (``token``, if any, is required
    on every request)."""
    app = FastAPI(title="motionweb", docs_url=None, redoc_url=None, openapi_url=None)

    @app.exception_handler(StarletteHTTPException)
    async def http_error(_: Request, exc: StarletteHTTPException) -> JSONResponse:
        return error(exc.status_code, str(exc.detail))  # e.g. no such route: JSON like every error

    @app.exception_handler(NotFound)
    async def not_found(_: Request, exc: NotFound) -> JSONResponse:
        return error(404, str(exc))

    @app.exception_handler(NotIndexed)
    async def not_indexed(_: Request, exc: NotIndexed) -> JSONResponse:
        return error(409, str(exc))

    @app.exception_handler(QueryCrashed)
    async def crashed(_: Request, exc: QueryCrashed) -> JSONResponse:
        return JSONResponse({"error": str(exc), "query": exc.query}, status_code=500)

    @app.exception_handler(ValidationError)
    async def invalid_model(_: Request, exc: ValidationError) -> JSONResponse:
        return error(400, "; ".join(f"{'.'.join(str(p) for p in e['loc'])}: {e['msg']}" for e in exc.errors()))

    @app.exception_handler(ValueError)
    async def bad_request(_: Request, exc: ValueError) -> JSONResponse:
        return error(400, str(exc).strip("'\""))

    @app.exception_handler(RequestValidationError)
    async def invalid(_: Request, exc: RequestValidationError) -> JSONResponse:
        return error(400, message(exc.errors()))

    @app.exception_handler(Exception)
    async def internal(_: Request, exc: Exception) -> JSONResponse:
        log.exception("request failed")
        return error(500, f"internal error ({type(exc).__name__}); see the service's log")

    async def run(fn, *args):
        """A blocking engine call in the thread pool (the event loop keeps serving)."""
        return await anyio.to_thread.run_sync(lambda: fn(*args))

    @app.get("/api/status")
    async def status() -> dict:
        return await run(engine.status)

    @app.get("/api/catalog")
    async def catalog(category: str | None = Query(None, max_length=200), name: str | None = Query(None, max_length=200),
                      min_s: float | None = None, max_s: float | None = None,
                      offset: int = Query(0, ge=0), limit: int = Query(500, ge=1, le=5000)) -> dict:
        return await run(engine.catalog, category, name, min_s, max_s, offset, limit)

    @app.get("/api/clips/{cid}/pose")
    async def clip_pose(cid: str, rate: float = Query(30.0, gt=0, le=120)) -> dict:
        return await run(engine.clip_pose, cid, rate)

    def download(name_text: tuple[str, str | bytes]) -> Response:
        name, text = name_text
        kind = "model/gltf-binary" if name.endswith(".glb") else "application/octet-stream"
        return Response(text, media_type=kind, headers={"Content-Disposition": f'attachment; filename="{name}"'})

    @app.get("/api/clips/{cid}/bvh")
    async def clip_bvh(cid: str) -> Response:
        return download(await run(engine.clip_bvh, cid))

    @app.get("/api/clips/{cid}/glb")
    async def clip_glb(cid: str) -> Response:
        return download(await run(engine.clip_glb, cid))

    @app.post("/api/search")
    async def search(body: SearchBody, request: Request) -> dict:
        if await request.is_disconnected():
            return error(499, "client went away")
        res = await run(engine.search, SearchQuery(**body.model_dump(exclude={"search"}, by_alias=True)), body.search)
        return res.summary()

    @app.get("/api/results/{rid}")
    async def result(rid: str) -> dict:
        return engine.result(rid).summary()

    @app.get("/api/results/{rid}/registration")
    async def registration(rid: str) -> dict:
        return await run(engine.register, rid)

    @app.get("/api/results/{rid}/nodes/{rank}/pose")
    async def node_pose(rid: str, rank: int, registered: bool = False) -> dict:
        return await run(engine.node_pose, rid, rank, registered)

    @app.get("/api/results/{rid}/nodes/{rank}/bvh")
    async def node_bvh(rid: str, rank: int, registered: bool = False) -> Response:
        return download(await run(engine.node_bvh, rid, rank, registered))

    @app.get("/api/results/{rid}/nodes/{rank}/glb")
    async def node_glb(rid: str, rank: int, registered: bool = False) -> Response:
        return download(await run(engine.node_glb, rid, rank, registered))

    @app.post("/api/query")
    async def query(body: QueryBody, request: Request) -> Response:
        if await request.is_disconnected():
            return error(499, "client went away")
        data = await run(engine.query_bundle, QueryRequest(**body.model_dump(exclude={"search"}, by_alias=True)), body.search)
        return Response(data, media_type="application/zip")

    spaces = Spaces(engine.cfg, on_query=engine.on_query)

    @app.get("/api/spaces")
    async def space_list() -> dict:
        return {"spaces": await run(spaces.summaries)}

    @app.get("/api/spaces/{sid}")
    async def space_detail(sid: str) -> dict:
        return await run(spaces.detail, sid)

    @app.post("/api/spaces/{sid}/synthesize")
    async def space_synthesize(sid: str, body: SynthesizeBody) -> dict:
        return await run(lambda: spaces.answer(*spaces.synthesize(sid, body.target), body.pose, body.bvh,
                                               MAX_DRAW_FRAMES))

    @app.post("/api/spaces/{sid}/blend")
    async def space_blend(sid: str, body: BlendBody) -> dict:
        return await run(lambda: spaces.answer(*spaces.blend(sid, body.weights), body.pose, body.bvh,
                                               MAX_DRAW_FRAMES))

    # ---------------------------------------------------------------- retime sessions (MPS06, sessions.py)
    retime = RetimeSessions(engine)
    app.state.retime_sessions = retime
    app.router.on_shutdown.append(retime.close)  # the session worker ends with the service

    @app.get("/api/retime/status")
    async def retime_status() -> dict:
        return await run(retime.worker_info)

    @app.post("/api/retime/sessions")
    async def retime_open(body: SessionBody) -> JSONResponse:
        return JSONResponse(await run(retime.create, body))

    # the edits' answers are plain JSON (floats, lists): serialized at once, not walked by FastAPI's
    # encoder (~30 ms for a 400-frame clip's poses and plots)
    @app.post("/api/retime/sessions/{sid}/edit")
    async def retime_edit(sid: str, body: EditBody) -> JSONResponse:
        return JSONResponse(await run(retime.edit, sid, body))

    @app.get("/api/retime/sessions/{sid}/bvh")
    async def retime_bvh(sid: str) -> Response:
        return download(await run(retime.bvh, sid))

    @app.get("/api/retime/sessions/{sid}/report")
    async def retime_report(sid: str) -> dict:
        return await run(retime.report, sid)

    warps = WarpSessions(retime)  # HDP07, in the same session worker
    engine.uploads = retime.uploads  # a search may name an upload (its webs kept with it)

    @app.post("/api/uploads")
    async def upload(body: UploadBody) -> JSONResponse:
        corpus = engine.cfg.corpus
        return JSONResponse(await run(retime.uploads.add, body, corpus.length_unit, corpus.scale_to_m))

    @app.get("/api/uploads/{uid}")
    async def upload_info(uid: str) -> dict:
        return retime.uploads.summary(retime.uploads.get(uid))

    @app.get("/api/uploads/{uid}/pose")
    async def upload_pose(uid: str, rate: float = Query(30.0, gt=0, le=120)) -> dict:
        return await run(engine.upload_pose, uid, rate)

    @app.post("/api/warp/sessions")
    async def warp_open(body: WarpSessionBody) -> dict:
        return await run(warps.create, body)

    @app.post("/api/warp/sessions/{sid}/edit")
    async def warp_edit(sid: str, body: WarpEditBody) -> JSONResponse:
        return JSONResponse(await run(warps.edit, sid, body))

    @app.get("/api/warp/sessions/{sid}/bvh")
    async def warp_bvh(sid: str) -> Response:
        return download(await run(warps.bvh, sid))

    static = static_dir()

    @app.get("/")
    async def page(request: Request) -> Response:
        resp = FileResponse(f"{static}/index.html", headers={"Cache-Control": "no-store"})
        t = request.query_params.get("token")
        if token and t:
            resp.set_cookie(TOKEN_COOKIE, t, httponly=True, samesite="strict")
        return resp

    app.mount("/static", StaticFiles(directory=static), name="static")
    return Guard(app, token, {"/api/uploads": retime.params.upload_bytes})
