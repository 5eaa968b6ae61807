"""The ``motionweb`` command line (typer). Each command is a thin shell over a flow or stage."""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, NoReturn, TypeVar

import typer
from motionweb.flows.commands.reported import ERRORS
from motionweb.flows.runtime.history import record_run, server_url

if TYPE_CHECKING:  # the config imports every stage: loaded on use, so a forwarded search starts fast
    from motionweb.flows.commands.requests import QueryRequest
    from motionweb.flows.config import Config

app = typer.Typer(
    name="motionweb",
    help="Search, blend and retime motion-capture libraries (KG04, HDP07, MPS06).",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


@app.callback()
def _main() -> None:
    """Search, blend and retime motion-capture libraries (KG04, HDP07, MPS06)."""
    _quiet_services()


def fail(message: str, code: int = 2) -> NoReturn:
    """Print a clear error (never a traceback) and exit non-zero."""
    typer.secho(f"error: {message}", err=True, fg=typer.colors.RED)
    raise typer.Exit(code)


T = TypeVar("T")
R = TypeVar("R")


def run_command(flow_name: str, parameters: dict[str, Any], work: Callable[[], T], show: Callable[[T], None],
                strip: bool = False, services: bool = False, record: bool = True,
                outcome: Callable[[T], Any] | None = None) -> T:
    """Every command's run, the same way (issue 23): with ``services`` (a command that may start a
    Prefect server or a Dask cluster) the reaper first, so they die with this process; then
    ``work`` in this process (an on-demand command calls its flow's ``.fn``: no Prefect,
    flows/runtime/lazy_prefect.py); an error it reports (``ERRORS``) is one line and exit 2 (quotes
    stripped with ``strip``); else ``show`` prints the answer. Either outcome is then recorded as
    a Prefect flow run named ``flow_name`` when a server is there (flows/runtime/history.py), unless
    ``record`` is off (a command that runs as a Prefect flow, index, is its own record); the record
    keeps ``outcome(result)`` (default: the result). An error with an ``exit_code``
    (:class:`~motionweb.flows.commands.reported.CommandError`) exits with that code."""
    if services:
        from motionweb.flows.runtime.reaper import start_reaper

        start_reaper()
    try:
        result = work()
    except ERRORS as exc:
        message = str(exc).strip("'\"") if strip else str(exc)
        if record:
            record_run(flow_name, parameters, {"error": message})
        fail(message, getattr(exc, "exit_code", 2))
    show(result)
    if record:
        record_run(flow_name, parameters, result if outcome is None else outcome(result))
    return result


def request_or_fail(model: type[R], **fields: Any) -> R:
    """A command's request model (flows/commands/requests.py) from its options; a bad one ends in ``fail``
    with the field named."""
    from motionweb.flows.commands.requests import parse

    try:
        return parse(model, **fields)
    except ValueError as exc:
        fail(str(exc))


def config_or_fail(path: Path | None) -> Config:
    """Load a config (the default one when ``path`` is None), turning errors into ``fail``."""
    from motionweb.flows.config import ConfigError, load_config
    from motionweb.flows.runtime.guard import report_into

    try:
        cfg = load_config(path)
    except ConfigError as exc:
        fail(str(exc))
        raise  # unreachable: fail() exits
    report_into(cfg.output)  # a crash report (flows/runtime/guard.py) goes to the output folder
    return cfg


def catalog_table(catalog) -> str:
    """A fixed-width table of a catalog's clips followed by its unreadable files."""
    rows = [("category", "clip", "frames", "fps", "seconds", "joints", "sha256")]
    rows += [
        (e.category, e.path, str(e.frames), f"{e.fps:g}", f"{e.duration:.2f}", str(e.n_joints), e.sha256[:12])
        for e in catalog.entries
    ]
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip() for r in rows]
    frames = sum(e.frames for e in catalog.entries)
    cats = len(catalog.by_category())
    lines.append(f"{len(catalog.entries)} clips, {cats} categories, {frames} frames")
    for err in catalog.errors:
        lines.append(f"skipped {err.path}: {err.reason}")
    return "\n".join(lines)


@app.command()
def catalog(
    corpus: Annotated[Path, typer.Argument(help="Folder of BVH / ASF+AMC / DeepMimic clips.")],
    config: Annotated[Path | None, typer.Option(help="Config for category rules and units.")] = None,
    json_out: Annotated[bool, typer.Option("--json", help="Print the catalog as JSON.")] = False,
) -> None:
    """Scan a corpus folder: category, frames, fps, duration and hash of every clip."""
    from motionweb.flows.commands.requests import CatalogRequest
    from motionweb.store.catalog import scan_corpus

    request = request_or_fail(CatalogRequest, corpus=str(corpus), as_json=json_out)
    cfg = config_or_fail(config)
    run_command("catalog", {"config": str(config) if config else None, "request": request.wire()},
                lambda: scan_corpus(request.corpus, cfg.corpus),
                lambda cat: typer.echo(cat.to_json() if request.as_json else catalog_table(cat)),
                outcome=lambda cat: {"clips": len(cat.entries), "frames": sum(e.frames for e in cat.entries),
                                     "unreadable": len(cat.errors)})


def _preview_default(name: str) -> Any:
    from motionweb.flows.commands.requests import PreviewRequest

    return PreviewRequest.model_fields[name].default


@app.command()
def preview(
    motion: Annotated[Path, typer.Argument(help="A clip (.bvh, .amc, DeepMimic .txt).")],
    out: Annotated[Path, typer.Option(help="Output GIF.")],
    max_frames: Annotated[int | None, typer.Option(
        help=f"Subsample to at most this many frames (default {_preview_default('max_frames')}).")] = None,
    fps: Annotated[float | None, typer.Option(help=f"GIF frame rate (default {_preview_default('fps'):g}).")] = None,
    up: Annotated[str | None, typer.Option(help=f"Vertical axis of the clip (default {_preview_default('up')}).")] = None,
) -> None:
    """Render a stick-figure animation of a clip to a GIF (headless)."""
    from motionweb.flows.commands.requests import PreviewRequest

    given = {k: v for k, v in {"max_frames": max_frames, "fps": fps, "up": up}.items() if v is not None}
    request = request_or_fail(PreviewRequest, motion=str(motion), out=str(out), **given)

    def work() -> dict[str, Any]:
        from motionweb.flows.preview import render_gif
        from motionweb.store.formats import read_motion

        m = read_motion(request.motion)
        n = render_gif(m, request.out, max_frames=request.max_frames, fps=request.fps, up=request.up)
        return {"out": request.out, "frames": n, "of": m.n_frames}

    run_command("preview", {"request": request.wire()}, work,
                lambda r: typer.echo(f"wrote {r['out']} ({r['frames']} frames of {r['of']})"))


@app.command()
def demo(
    workdir: Annotated[Path, typer.Option(help="Folder for the demo corpus, store and outputs.")] = Path(
        "motionweb-demo"
    ),
    config: Annotated[Path | None, typer.Option(help="Config (default: configs/demo.yaml).")] = None,
) -> None:
    """Generate the synthetic demo corpus, index it (Zarr store, local Dask) and search it.

    The run's config is written to WORKDIR/config.yaml (paths relative to it), so every later
    command can be pointed at the same corpus and store: ``motionweb index WORKDIR/config.yaml``.
    """
    import yaml
    from motionweb.flows.config import packaged_config
    from motionweb.store.catalog import scan_corpus
    from motionweb.store.demo.corpus import write_demo_corpus

    cfg = config_or_fail(config or packaged_config("demo.yaml"))
    workdir.mkdir(parents=True, exist_ok=True)
    data = cfg.model_dump(mode="json")
    data["corpus"]["path"], data["store"]["path"], data["output"] = "corpus", "store", "out"
    cfg_path = workdir / "config.yaml"
    cfg_path.write_text("# written by `motionweb demo`; paths are relative to this file\n"
                        + yaml.safe_dump(data, sort_keys=False))
    cfg = config_or_fail(cfg_path)
    from motionweb.flows.runtime import warmup
    from motionweb.flows.runtime.reaper import start_reaper

    start_reaper()  # the warm-up processes and the services end with this process
    # the index kernels compile in parallel processes and Prefect's local server starts while the
    # corpus is written (flows/runtime/warmup.py), and the search kernels in one more process at low
    # priority, on the core the index's start-up leaves idle: the cold demo's compile time,
    # overlapped (not the BVH reader: the corpus scan below calls it before any share is done)
    ahead = [warmup.start(["index"]), warmup.start_prefect()]
    search_ahead = warmup.start(["search"], processes=1, nice=10)
    files = write_demo_corpus(cfg.corpus.path, seed=cfg.demo.seed,
                              variants_per_category=cfg.demo.variants_per_category, fps=cfg.demo.fps,
                              variants=cfg.demo.variants)
    typer.echo(f"demo corpus: {len(files)} clips in {cfg.corpus.path}")
    typer.echo(catalog_table(scan_corpus(cfg.corpus.path, cfg.corpus)))
    typer.echo(f"\nindexing (KG04 match webs) with {cfg_path} ...")
    run_index(cfg, progress=True, ahead=ahead)
    search_ahead.wait()
    from motionweb.flows.commands.requests import QueryRequest

    d = cfg.demo
    typer.echo(f"\nsearching (KG04 §3.3) for {d.query_clip} {d.query_start:g}-{d.query_end:g} s, registering the matches ...")
    run_query(cfg, QueryRequest(clip=d.query_clip, start=d.query_start, end=d.query_end,
                                quantile=d.query_quantile, register=True))
    typer.echo(f"next: motionweb search {cfg_path} --clip CLIP --start S --end E --quantile Q "
               "(see motionweb search --help)")


@app.command()
def warp(
    input_path: Annotated[Path, typer.Argument(metavar="INPUT", help="Clip to warp (.bvh, .amc, DeepMimic .txt).")],
    out: Annotated[Path, typer.Option(help="Output BVH.")],
    reference: Annotated[Path | None, typer.Option(help="Timing reference (default: the input).")] = None,
    duration: Annotated[float | None, typer.Option(help="Output duration, seconds.")] = None,
    frames: Annotated[int | None, typer.Option(help="Output length, frames.")] = None,
    unconstrained: Annotated[bool, typer.Option(help="No output length: plain DAG shortest path.")] = False,
    keytime: Annotated[list[str] | None, typer.Option(help="IN_S:OUT_S, input time shown at output time.")] = None,
    skip: Annotated[int | None, typer.Option(help="Skip limit s (default from the config, 8).")] = None,
    fast: Annotated[bool, typer.Option(help="HDP07 §3.3 heuristic: coarse solve, then a band.")] = False,
    backward: Annotated[bool, typer.Option(help="Play the input backwards.")] = False,
    plot: Annotated[Path | None, typer.Option(help="Warp curve PNG (HDP07 Fig. 2 style).")] = None,
    config: Annotated[Path | None, typer.Option(help="Config file (warp section).")] = None,
) -> None:
    """Guided time warp (HDP07): retime a clip to a duration and keytimes, mimicking a reference's timing."""
    keys = [parse_pair("--keytime", text, "IN_S:OUT_S (seconds), e.g. 1.5:1.0") for text in keytime or []]
    from motionweb.flows.commands.requests import WarpRequest

    request = request_or_fail(WarpRequest, input=str(input_path), out=str(out),
                              reference=str(reference) if reference else None, duration=duration, frames=frames,
                              unconstrained=unconstrained, keytimes=tuple(keys), skip=skip, fast=fast,
                              backward=backward, plot=str(plot) if plot else None)
    cfg = config_or_fail(config)
    from motionweb.flows.warp import format_summary
    from motionweb.flows.warp import warp as warp_flow

    params = {"config": str(config) if config else None, "request": request.wire()}
    run_command("guided-warp", params, lambda: warp_flow.fn(cfg, request),  # its plan checks first
                lambda summary: typer.echo(format_summary(summary)))


def parse_pair(option: str, text: str, expected: str) -> tuple[float, float]:
    """``A:B`` as two floats (one-line failure naming the option)."""
    try:
        a, b = text.split(":")
        return float(a), float(b)
    except ValueError:
        fail(f"{option} {text!r}: expected {expected}")


def body_factors(option: str, texts: list[str] | None) -> dict[str, float]:
    """``JOINT=FACTOR`` options as ``{joint: factor}`` (one-line failure for a malformed one)."""
    factors = {}
    for text in texts or []:
        name, _, val = text.partition("=")
        try:
            factors[name] = float(val)
            if not factors[name] > 0:
                raise ValueError
        except ValueError:
            fail(f"{option} {text!r}: expected JOINT=FACTOR with a positive factor, e.g. lfemur=10")
    return factors


@app.command()
def retime(
    input_path: Annotated[Path, typer.Argument(metavar="INPUT", help="Clip to retime (.bvh, .amc, DeepMimic .txt).")],
    out: Annotated[Path, typer.Option(help="Output BVH (a JSON report is written beside it).")],
    duration: Annotated[float | None, typer.Option(help="Output duration, seconds.")] = None,
    keytime: Annotated[list[str] | None, typer.Option(help="SRC_S:OUT_S, source time shown at output time.")] = None,
    gravity: Annotated[str | None, typer.Option(help="Gravity vector X,Y,Z in m/s² (default 0,-9.81,0 for Y up).")] = None,
    mass: Annotated[list[str] | None, typer.Option(help="JOINT=FACTOR, multiply a body's mass (inertia and weight).")] = None,
    weight_factors: Annotated[list[str] | None, typer.Option(
        "--weight", help="JOINT=FACTOR, multiply only a body's weight (gravity load), its inertia kept (MPS06 Fig. 11).")] = None,
    objective: Annotated[str | None, typer.Option(help="match (original torques) or minimize (effort).")] = None,
    plot: Annotated[Path | None, typer.Option(help="Folder for p(t) and feasible-polygon plots.")] = None,
    config: Annotated[Path | None, typer.Option(help="Config file (retime section).")] = None,
) -> None:
    """Physics-based retiming (MPS06): change duration, keytimes, gravity, limb masses or weights."""
    keys = [parse_pair("--keytime", text, "SRC_S:OUT_S (seconds), e.g. 1.5:1.0") for text in keytime or []]
    g = None
    if gravity is not None:
        try:
            g = [float(v) for v in gravity.split(",")]
            if len(g) != 3:
                raise ValueError
        except ValueError:
            fail(f"--gravity {gravity!r}: expected X,Y,Z, e.g. 0,-4.9,0")
    from motionweb.flows.commands.requests import RetimeRequest

    request = request_or_fail(RetimeRequest, input_path=str(input_path), out=str(out), duration=duration,
                              keytimes=keys, gravity=g, mass=body_factors("--mass", mass),
                              weight_factors=body_factors("--weight", weight_factors),  # the same name down to
                              objective=objective, plot_dir=str(plot) if plot else None)  # RetimePlan
    cfg = config_or_fail(config)
    from motionweb.flows.retime import retime_flow

    params = {"config": str(config) if config else None, "request": request.wire()}
    run_command("retime", params, lambda: retime_flow.fn(request.input_path, cfg, request.out,
                                                         **request.model_dump(exclude={"input_path", "out"})),
                print_retime)


def print_retime(rep: dict) -> None:
    """What ``motionweb retime`` prints: durations, flights, notes, the reachable duration."""
    typer.echo(f"{rep['clip']}: {rep['duration_in']:.3f} s -> {rep['duration_out']:.3f} s, "
               f"{rep['frames_out']} frames written to {rep['output']}")
    for fl in rep["flights"]:
        typer.echo(f"  flight {fl['source_duration']:.3f} s -> {fl['output_duration']:.3f} s (x{fl['ratio']:.2f})"
                   + (f", not ballistic: its centre of mass falls at {fl['falls_at']:.1f} m/s², not "
                      f"{rep['free_fall']['expected']:.1f} (more than the feet holds or pushes it, or the contacts "
                      "are off)" if fl["held_up"] else ""))
    if rep["free_fall"]["note"]:
        typer.echo(f"  check the unit: {rep['free_fall']['note']}")
    for what in rep["glitches_mended"]:
        typer.echo(f"  capture glitch mended for the dynamics (the output keeps it): {what}")
    if rep["infeasible_source_frames"]:
        typer.echo(f"  source frames the contact model cannot explain: {rep['infeasible_source_frames']}")
    if rep["infeasible_output_frames"]:
        typer.echo(f"  output frames outside their feasible polygon: {len(rep['infeasible_output_frames'])}")
    typer.echo(f"  timing ({rep['timing']}) {rep['reachable']['message']}")


def _quiet_services() -> None:
    """Defaults for runs from the CLI: no telemetry, terse Dask logs, patient server start."""
    import os

    os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
    os.environ.setdefault("DASK_LOGGING__DISTRIBUTED", "warning")
    # the CLI shows its own progress counter; PREFECT_LOGGING_LEVEL=INFO shows the flow's log too
    os.environ.setdefault("PREFECT_LOGGING_LEVEL", "WARNING")
    # Prefect's ephemeral API server gets 20 s to start by default: too little on a busy 2-core box
    os.environ.setdefault("PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS", "120")


def run_index(cfg: Config, progress: bool, ahead: list | None = None) -> dict:
    """Run the index with an optional progress counter on stderr (:func:`run_command`, which
    starts the reaper: the Prefect server and Dask workers die with this process).

    With work to do and Prefect's local server to start, the index kernels compile in parallel
    processes meanwhile (flows/runtime/warmup.py :func:`~motionweb.flows.runtime.warmup.ahead_of_index`), and the
    flow starts when both are done; ``ahead``: those already started by the caller (``demo``,
    before it writes its corpus)."""
    import motionweb.flows.index as idx
    from motionweb.flows.runtime import warmup

    seen: dict[str, tuple[int, int]] = {}

    def show(stage: str, done: int, total: int) -> None:
        """One line summing the chunks' counters per stage ("features 27/27  webs 40/54")."""
        seen[stage] = (done, total)
        sums: dict[str, list[int]] = {}
        for name, (d, t) in seen.items():
            acc = sums.setdefault(name.split("[")[0], [0, 0])
            acc[0] += d
            acc[1] += t
        typer.echo("\r  " + "  ".join(f"{k} {d}/{t}" for k, (d, t) in sums.items()), err=True, nl=False)

    def work() -> dict:
        idx.PROGRESS = show if progress and sys.stderr.isatty() else None  # no \r lines in a log file
        try:
            # nothing to compute, commit or repair, and no Prefect server to record the run: said
            # without Prefect, its server or a Dask cluster (flows/index.py unchanged_summary)
            handover: dict = {}
            summary = idx.unchanged_summary(cfg, handover) if server_url() is None else None
            if summary is not None:
                return summary
            for started in ahead if ahead is not None else warmup.ahead_of_index(cfg.dask.address is None):
                started.wait()
            idx.VERIFIED = handover or None  # what it verified is not read again by the flow's plan
            return idx.index_library(cfg)
        finally:
            idx.PROGRESS = idx.VERIFIED = None
            if seen:
                typer.echo("", err=True)

    # the flow run is its own record: nothing recorded twice (record=False)
    return run_command("index-library", {}, work, lambda summary: typer.echo(idx.format_summary(summary)),
                       services=True, record=False)


@app.command()
def index(
    config: Annotated[Path, typer.Argument(help="Config file (corpus, features, matchweb, dask, store, index).")],
    progress: Annotated[bool, typer.Option(help="Show a progress counter on stderr (when it is a terminal).")] = True,
) -> None:
    """Index the corpus into match webs (Prefect flow); print the run summary."""
    run_index(config_or_fail(config), progress)


@app.command()
def serve(
    config: Annotated[Path, typer.Argument(help="Config file; its index.schedule is the cron.")],
    name: Annotated[str, typer.Option(help="Deployment name.")] = "nightly",
) -> None:
    """Serve the index flow as a Prefect deployment on the config's nightly cron (blocks)."""
    import os

    cfg = config_or_fail(config)
    from motionweb.flows.index import index_library

    if not os.environ.get("PREFECT_API_URL"):
        typer.secho("warning: PREFECT_API_URL is not set; scheduled runs need a Prefect server "
                    "(`prefect server start`, then export PREFECT_API_URL)", err=True, fg=typer.colors.YELLOW)
    typer.echo(f"serving index-library/{name} on cron {cfg.index.schedule!r} for {config.resolve()}")
    index_library.serve(name=name, cron=cfg.index.schedule, parameters={"config": str(config.resolve())})


def matches_table(rows: list[dict]) -> str:
    """Fixed-width table of query results (rank, clip, category, frames, seconds, cost, tier, distance)."""
    head = ("rank", "clip", "category", "frames", "seconds", "cost", "tier", "distance")
    body = [(str(r["rank"]), r["clip"], r["category"], f"{r['start_frame']}-{r['end_frame']}",
             f"{r['start_s']:.2f}-{r['end_s']:.2f}", f"{r['cost']:.4g}", str(r["tier"]), f"{r['distance']:.4g}")
            for r in rows]
    widths = [max(len(x[i]) for x in [head, *body]) for i in range(len(head))]
    return "\n".join("  ".join(c.ljust(w) for c, w in zip(x, widths, strict=True)).rstrip() for x in [head, *body])


def run_query(cfg: Config, request: QueryRequest, query_file: Path | None = None) -> dict:
    """Check the request, run the query flow's body here and print its matches (:func:`run_command`).
    With ``query_file`` the query is that clip, from outside the index (its webs built on demand)."""
    from motionweb.flows.query import plan_query, query

    def work() -> dict:
        motion = None
        if query_file is not None:
            from motionweb.flows.config import load_motion  # the config's unit for a BVH that declares none

            motion = load_motion(query_file, cfg)
        return query.fn(cfg, request, plan_query(cfg, request, motion))  # resolved once

    params = {"store": cfg.store.path, "request": request.wire(), "query_file": str(query_file) if query_file else None}
    return run_command("query", params, work, print_query, strip=True)


def print_query(res: dict) -> None:
    """The query line, the matches table and where the outputs are."""
    q = res["query"]
    eps = "none" if res["epsilon"] is None else f"{res['epsilon']:.4g}"
    typer.echo(f"query {q['clip']} frames {q['start_frame']}-{q['end_frame']} at {q['rate']:g} Hz, "
               f"ε = {eps}, generation {res['generation']}")
    if res.get("message"):
        typer.echo(f"no matches: {res['message']}")
    elif not res["matches"]:
        typer.echo("no matches: raise --threshold / --quantile, or search --all-categories")
    else:
        typer.echo(matches_table(res["matches"]))
    via = f" (by the service at {res['service']})" if res.get("service") else ""
    typer.echo(f"{len(res['matches'])} matches in {res['timings']['search_s']:.2f} s{via}; outputs in {res['out']}")


@app.command()
def search(
    config: Annotated[Path, typer.Argument(help="Config file (store, search, output).")],
    start: Annotated[float, typer.Option(help="Query start, seconds.")],
    end: Annotated[float, typer.Option(help="Query end, seconds.")],
    clip: Annotated[str | None, typer.Option(help="Query clip: corpus path or file stem.")] = None,
    query_file: Annotated[Path | None, typer.Option(help="Query clip from outside the index (.bvh, .amc, DeepMimic .txt): its webs against the indexed clips are built on demand.")] = None,
    threshold: Annotated[float | None, typer.Option(help="Absolute threshold ε on average web values (default: search.eps_nearest_ratio × the query's nearest match).")] = None,
    quantile: Annotated[float | None, typer.Option(help="ε as this quantile (0-1) of the searched webs' values.")] = None,
    tiers: Annotated[int | None, typer.Option(help="Search tiers (default: config search.max_tiers).")] = None,
    all_categories: Annotated[bool, typer.Option(help="Search every chunk, not only the query's category.")] = False,
    register: Annotated[bool, typer.Option(help="Register the matches: warps.csv/png, registered BVH.")] = False,
    export: Annotated[Path | None, typer.Option(help="Write every match as BVH into this folder.")] = None,
    out: Annotated[Path | None, typer.Option(help="Output folder (default: the config's output).")] = None,
    format: Annotated[str, typer.Option("--format", help="Exported and registered motions: bvh or glb (glTF binary).")] = "bvh",
) -> None:
    """Search the index for motions like CLIP[START, END] (KG04 §3.3); print the matches.

    With a `motionweb app` running for the config's store, the service answers (same outputs)."""
    from motionweb.flows.app.client import ServiceError, forward_search
    from motionweb.flows.commands.requests import QueryRequest

    if (clip is None) == (query_file is None):
        fail("give exactly one of --clip NAME (an indexed clip) and --query-file FILE (a clip from outside the index)")
    if query_file is not None:
        clip = query_file.name
    request = request_or_fail(QueryRequest, clip=clip, start=start, end=end, threshold=threshold, quantile=quantile,
                              tiers=tiers, all_categories=all_categories or None, register=register,
                              export=str(export) if export else None, out=str(out) if out else None, format=format)
    if query_file is not None:  # a file is searched here: no request names a path to the service
        run_query(config_or_fail(config), request, query_file)
        return
    try:
        res = forward_search(config, request)
    except ServiceError as exc:
        fail(str(exc))
    if res is not None:
        print_query(res)
        return
    run_query(config_or_fail(config), request)


@app.command("app")
def app_command(
    config: Annotated[Path, typer.Argument(help="Config file (store, search).")],
    host: Annotated[str, typer.Option(help="Address to listen on (loopback unless --token is given).")] = "127.0.0.1",
    port: Annotated[int, typer.Option(help="Port (0: any free one).")] = 8765,
    token: Annotated[str | None, typer.Option(help="Secret every request must carry (required off loopback).")] = None,
    record: Annotated[bool, typer.Option(help="Record every query as a Prefect flow run.")] = True,
) -> None:
    """Serve the web page and JSON API for on-demand queries of the config's store (blocks)."""
    cfg = config_or_fail(config)
    from motionweb.flows.app.server import serve
    from motionweb.flows.runtime.reaper import start_reaper

    start_reaper()  # a Prefect server the service starts dies with it, even when it is killed
    try:
        serve(cfg, host, port, token, record, on_ready=lambda url: typer.echo(f"motionweb app: {url}"))
    except ValueError as exc:
        fail(str(exc))


@app.command("plot-web")
def plot_web(
    config: Annotated[Path, typer.Argument(help="Config file (corpus, features, matchweb).")],
    clip_a: Annotated[str, typer.Argument(help="Clip on the vertical axis (corpus path or stem).")],
    clip_b: Annotated[str, typer.Argument(help="Clip on the horizontal axis (corpus path or stem).")],
    out: Annotated[Path | None, typer.Option(help="Output image (PNG, PDF, SVG; default web.png).")] = None,
) -> None:
    """Draw the distance grid of two clips with minima, valid region, chains and bridges (KG04 Fig. 4/7)."""
    from motionweb.flows.commands.requests import PlotWebRequest

    request = request_or_fail(PlotWebRequest, clip_a=clip_a, clip_b=clip_b, **({"out": str(out)} if out else {}))
    cfg = config_or_fail(config)

    def work() -> Any:
        from motionweb.flows.plots import plot_web as draw

        return draw(cfg, request.clip_a, request.clip_b, request.out)

    run_command("plot-web", {"config": str(config), "request": request.wire()}, work,
                lambda rep: typer.echo(f"wrote {rep.out}: {rep.clip_a} x {rep.clip_b} at {rep.rate:g} Hz, grid "
                                       f"{rep.shape[0]}x{rep.shape[1]}, {rep.minima} minima, {rep.chains} chains, "
                                       f"{rep.bridges} bridges"),
                strip=True, outcome=lambda rep: {"out": str(rep.out), "grid": list(rep.shape), "chains": rep.chains,
                                                 "bridges": rep.bridges})


from motionweb.flows.commands import store_cli

app.command()(store_cli.verify)
app.command()(store_cli.gc)


from motionweb.flows.commands.space_cli import add_commands

add_commands(app, fail, config_or_fail)

from motionweb.flows.commands.export_cli import register as add_exports

add_exports(app)


def main() -> None:
    """The console script: run the CLI, and turn anything a command did not foresee (a Prefect
    server that fails to start, a full disk) into one line on stderr, exit 1, instead of a
    traceback. ``MOTIONWEB_DEBUG=1`` shows the traceback. :func:`motionweb.flows.runtime.guard.protect`
    first: the services it starts never hold the caller's stdio, and a crash prints one line."""
    import os

    from motionweb.flows.runtime.guard import protect

    protect(" ".join(["motionweb", *sys.argv[1:2]]))
    code: int | str | None = 0
    try:
        app()
    except SystemExit as exc:  # typer ends every command so
        code = exc.code
    except Exception as exc:
        if os.environ.get("MOTIONWEB_DEBUG"):
            raise
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
        typer.secho(f"error: {type(exc).__name__}: {first} (MOTIONWEB_DEBUG=1 shows where)", err=True,
                    fg=typer.colors.RED)
        code = 1
    finish(code)


def finish(code: int | str | None) -> None:
    """End the process once the command is done: the exit handlers (services stopped, temporary
    servers ended, files closed), the standard streams flushed, then ``os._exit``. Python's own
    teardown of every loaded module (Prefect, Dask, numba, matplotlib: ~1.4 s after a demo on 2
    cores) is skipped: the command has nothing left to write by then."""
    import atexit
    import os

    if isinstance(code, str):  # sys.exit("message"): printed, exit 1, as Python does
        print(code, file=sys.stderr)
        code = 1
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(code or 0)


if __name__ == "__main__":
    main()
