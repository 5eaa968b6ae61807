"""``motionweb export``, ``motionweb mirror`` and ``motionweb cleanup``: a clip written for
animators' tools (design "Exports"). The work is in the stages (tasks/mirror.py,
tasks/cleanup.py, tasks/rootmotion.py) and the writers in store/ (store.formats.write_motion:
BVH or GLB by the output's suffix or ``--format``); this module only parses options, loads the
config and prints one line."""

from __future__ import annotations

from enum import Enum
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

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


def _load(config: Path | None, input_path: Path) -> tuple[Config, Motion]:
    from motionweb.flows.cli import config_or_fail, fail
    from motionweb.flows.reported import ERRORS
    from motionweb.store.formats import read_motion

    cfg = config_or_fail(config)
    if not input_path.is_file():
        fail(f"{input_path}: no such file")
    try:
        return cfg, read_motion(input_path, unit=cfg.corpus.length_unit, scale_to_m=cfg.corpus.scale_to_m)
    except ERRORS as exc:
        fail(str(exc).strip("'\""))
        raise  # unreachable: fail() exits


def _write(cfg: Config, motion: Motion, out: Path, fmt: Format | None, root: RootMode | None) -> str:
    """Write through the stages and store.formats.write_motion; returns what was written, or
    fails with one line naming the file."""
    from motionweb.flows.cli import fail
    from motionweb.flows.reported import ERRORS
    from motionweb.store.formats import motion_format, write_motion
    from motionweb.tasks.rootmotion import root_motion

    params = cfg.root_motion if root is None else cfg.root_motion.model_copy(update={"mode": root.value})
    try:
        kind = motion_format(out, fmt.value if fmt else None)
        moved = root_motion(motion, params, up=cfg.corpus.up_axis)
        out.parent.mkdir(parents=True, exist_ok=True)
        write_motion(moved, out, kind, up=cfg.corpus.up_axis)
    except ERRORS as exc:
        fail(str(exc).strip("'\""))
    extra = ", root motion on its own joint" if params.mode == "in-place" else ""
    return f"wrote {out} ({kind.upper()}): {motion.n_frames} frames at {motion.fps:g} fps{extra}"


def export(input_path: Input, out: Out, format: Fmt = None, root_motion: Root = None,
           config: ConfigOpt = None) -> None:
    """Write a clip as BVH or GLB (glTF 2.0 binary: a skinned figure and one animation, metres,
    Y up), optionally with its root motion on a root joint of its own."""
    cfg, motion = _load(config, input_path)
    typer.echo(_write(cfg, motion, out, format, root_motion))


def mirror(input_path: Input, out: Out, format: Fmt = None, root_motion: Root = None,
           config: ConfigOpt = None) -> None:
    """Mirror a clip left/right across the character's sagittal plane (pairs found from the
    joint names; the config's mirror.pairs overrides them)."""
    from motionweb.flows.cli import fail
    from motionweb.tasks.mirror import mirror as mirror_motion

    cfg, motion = _load(config, input_path)
    try:
        res = mirror_motion(motion, cfg.mirror)
    except ValueError as exc:
        fail(f"{input_path}: {exc}")
    line = _write(cfg, res.motion, out, format, root_motion)
    unit = "m" if motion.scale_to_m else "file units"
    typer.echo(f"{line}; {len(res.pairs)} left/right pairs, plane normal {'xyz'[res.axis]}, "
               f"skeleton asymmetry {res.asymmetry:.4g} {unit}")


def cleanup(input_path: Input, out: Out, format: Fmt = None, root_motion: Root = None,
            config: ConfigOpt = None) -> None:
    """Hold detected foot plants still with the leg IK blending uses; prints the foot skate
    (mean horizontal ankle speed on planted frames) before and after, in cm/s."""
    from motionweb.flows.cli import fail
    from motionweb.tasks.cleanup import cleanup as cleanup_motion

    cfg, motion = _load(config, input_path)
    try:
        res = cleanup_motion(motion, cfg.blend, up=cfg.corpus.up_axis)
    except ValueError as exc:
        fail(f"{input_path}: {exc}")
    line = _write(cfg, res.motion, out, format, root_motion)
    typer.echo(f"{line}; foot skate {res.skate_before:.2f} -> {res.skate_after:.2f} cm/s on "
               f"{int(res.plants.sum())} planted foot-frames, worst IK miss {100 * res.miss_m:.2f} cm")


def register(app: typer.Typer) -> None:
    """Add the three commands to the CLI."""
    app.command("export")(export)
    app.command("mirror")(mirror)
    app.command("cleanup")(cleanup)
