"""``motionweb export``, ``motionweb mirror`` and ``motionweb cleanup``: a clip written for
animators' tools (design "Exports"). The work is in the stages (tasks/mirror.py,
tasks/cleanup.py, tasks/rootmotion.py) and the writers in store/ (store.formats.write_motion:
BVH or GLB by the output's suffix or ``--format``); this module only parses options, loads the
config and prints one line."""

from __future__ import annotations

from collections.abc import Callable
from enum import Enum
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from motionweb.flows.commands.requests import ExportRequest

if TYPE_CHECKING:
    from motionweb.flows.config import Config
    from motionweb.store.motion import Motion


class Format(str, Enum):
    bvh = "bvh"
    glb = "glb"
    fbx = "fbx"


class RootMode(str, Enum):
    keep = "keep"
    in_place = "in-place"


Input = Annotated[Path, typer.Argument(metavar="INPUT", help="A clip (.bvh, .amc, DeepMimic .txt).")]
Out = Annotated[Path, typer.Option(help="Output motion: .bvh, .glb (glTF binary) or .fbx (through Blender), or as --format says.")]
Fmt = Annotated[Format | None, typer.Option("--format", help="Output format (default: the --out suffix).")]
Root = Annotated[RootMode | None, typer.Option(
    "--root-motion", help="in-place: the hips' ground travel and heading on a root joint of their own "
                          "(default: the config's root_motion.mode).")]
ConfigOpt = Annotated[Path | None, typer.Option(help="Config (corpus unit and up axis, mirror, blend, root_motion).")]


def _load(cfg: Config, request: ExportRequest) -> Motion:
    """The request's clip, read with the config's unit (ValueError naming a missing file)."""
    from motionweb.flows.config import load_motion

    return load_motion(request.input, cfg)


def _write(cfg: Config, motion: Motion, request: ExportRequest) -> str:
    """Write through the stages and store.formats.write_motion; what was written (ValueError
    naming the file otherwise)."""
    from motionweb.store.formats import motion_format, write_motion
    from motionweb.tasks.rootmotion import root_motion

    params = cfg.root_motion if request.root_motion is None else cfg.root_motion.model_copy(
        update={"mode": request.root_motion})
    out = Path(request.out)
    kind = motion_format(out, request.format)
    moved = root_motion(motion, params, up=cfg.corpus.up_axis)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_motion(moved, out, kind, up=cfg.corpus.up_axis)
    extra = ", root motion on its own joint" if params.mode == "in-place" else ""
    return f"wrote {out} ({kind.upper()}): {motion.n_frames} frames at {motion.fps:g} fps{extra}"


def _run(name: str, input_path: Path, out: Path, format: Format | None, root_motion: RootMode | None,
         config: Path | None, work: Callable[[Config, Motion, ExportRequest], str]) -> None:
    """One export-like command through the command core: its request model, the config, then
    ``work`` (the line to print) under :func:`motionweb.flows.commands.cli.run_command`."""
    from motionweb.flows.commands.cli import config_or_fail, request_or_fail, run_command

    request = request_or_fail(ExportRequest, input=str(input_path), out=str(out),
                              format=format.value if format else None,
                              root_motion=root_motion.value if root_motion else None)
    cfg = config_or_fail(config)
    run_command(name, {"config": str(config) if config else None, "request": request.wire()},
                lambda: {"line": work(cfg, _load(cfg, request), request)}, lambda r: typer.echo(r["line"]),
                strip=True)


def export(input_path: Input, out: Out, format: Fmt = None, root_motion: Root = None,
           config: ConfigOpt = None) -> None:
    """Write a clip as BVH or GLB (glTF 2.0 binary: a skinned figure and one animation, metres,
    Y up), optionally with its root motion on a root joint of its own."""
    _run("export", input_path, out, format, root_motion, config, _write)


def mirror(input_path: Input, out: Out, format: Fmt = None, root_motion: Root = None,
           config: ConfigOpt = None) -> None:
    """Mirror a clip left/right across the character's sagittal plane (pairs found from the
    joint names; the config's mirror.pairs overrides them)."""

    def work(cfg: Config, motion: Motion, request: ExportRequest) -> str:
        from motionweb.tasks.mirror import mirror as mirror_motion

        try:
            res = mirror_motion(motion, cfg.mirror)
        except ValueError as exc:
            raise ValueError(f"{request.input}: {exc}") from None
        unit = "m" if motion.scale_to_m else "file units"
        return (f"{_write(cfg, res.motion, request)}; {len(res.pairs)} left/right pairs, plane normal "
                f"{'xyz'[res.axis]}, skeleton asymmetry {res.asymmetry:.4g} {unit}")

    _run("mirror", input_path, out, format, root_motion, config, work)


def cleanup(input_path: Input, out: Out, format: Fmt = None, root_motion: Root = None,
            config: ConfigOpt = None) -> None:
    """Hold detected foot plants still with the leg IK blending uses; prints the foot skate
    (mean horizontal ankle speed on planted frames) before and after, in cm/s."""

    def work(cfg: Config, motion: Motion, request: ExportRequest) -> str:
        from motionweb.tasks.cleanup import cleanup as cleanup_motion

        try:
            res = cleanup_motion(motion, cfg.blend, up=cfg.corpus.up_axis)
        except ValueError as exc:
            raise ValueError(f"{request.input}: {exc}") from None
        return (f"{_write(cfg, res.motion, request)}; foot skate {res.skate_before:.2f} -> {res.skate_after:.2f} "
                f"cm/s on {int(res.plants.sum())} planted foot-frames, worst IK miss {100 * res.miss_m:.2f} cm")

    _run("cleanup", input_path, out, format, root_motion, config, work)


def register(app: typer.Typer) -> None:
    """Add the three commands to the CLI."""
    app.command("export")(export)
    app.command("mirror")(mirror)
    app.command("cleanup")(cleanup)
