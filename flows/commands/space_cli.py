"""``motionweb parameterize`` / ``synthesize`` / ``blend``: thin commands over ``flows/space.py``
(KG04 §4). Registered on the main app by ``flows/commands/cli.py``; every input is checked before a flow
starts and a bad one ends in one line (exit 2)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any, NoReturn

import typer
from motionweb.flows.app.client import ServiceError, forward_space


def parse_target(text: str) -> list[float]:
    try:
        return [float(v) for v in text.split(",")]
    except ValueError:
        raise ValueError(f"--target {text!r}: expected numbers separated by commas, e.g. 0.3,1.2,0.5") from None


def synthesis_line(out: Path, frames: int, achieved, error: float, outside: bool, service: str | None = None) -> str:
    """What ``synthesize`` prints: the file, its frames, the achieved parameter and the error."""
    got = ",".join(f"{v:.4f}" for v in achieved)
    note = " (outside the accessible region: projected)" if outside else ""
    via = f" (by the service at {service})" if service else ""
    return f"wrote {out}: {frames} frames; achieved {got}, {100 * error:.2f} cm from the target{note}{via}"


def parse_weights(items: list[str]) -> dict[str, float]:
    out = {}
    for text in items:
        clip, eq, value = text.rpartition("=")
        try:
            if not eq or not clip:
                raise ValueError
            out[clip] = float(value)
        except ValueError:
            raise ValueError(f"--weights {text!r}: expected CLIP=WEIGHT, e.g. walk_01=0.6") from None
    return out


def ask_service(fail: Callable[[str], NoReturn], config: Path | None, space: str, op: str,
                payload: Callable[[], dict], out: Path) -> tuple[Any, dict | None]:
    """The parsed request (``op``'s model: :class:`SynthesizeRequest` or :class:`BlendRequest`,
    the bodies the service's routes take) and, when a `motionweb app` serves the config's store,
    its answer (None otherwise); a bad option or the service's refusal ends in ``fail``."""
    from motionweb.flows.commands.requests import BlendRequest, SynthesizeRequest, parse

    try:
        body = parse(SynthesizeRequest if op == "synthesize" else BlendRequest, **payload())
        return body, forward_space(config, space, op, body.wire(), out)
    except (ValueError, ServiceError) as exc:
        fail(str(exc).strip("'\""))


def add_commands(app: typer.Typer, fail: Callable[[str], None], config_or_fail: Callable) -> None:
    """Register the motion-space commands on ``app`` (``fail`` prints one line and exits 2)."""

    @app.command()
    def parameterize(
        config: Annotated[Path, typer.Argument(help="Config file (store, search, blend, parameterize).")],
        clip: Annotated[str, typer.Option(help="Query clip: corpus path or file stem.")],
        start: Annotated[float, typer.Option(help="Query start, seconds.")],
        end: Annotated[float, typer.Option(help="Query end, seconds.")],
        param: Annotated[str, typer.Option(help="KIND[:JOINT[@SECONDS]]: position:JOINT@S, final_root, lowest_hip, "
                                                "max_speed:JOINT, custom:module.function (runs that code).")],
        threshold: Annotated[float | None, typer.Option(help="Absolute threshold ε.")] = None,
        quantile: Annotated[float | None, typer.Option(help="ε as this quantile (0-1) of the webs' values.")] = None,
        samples: Annotated[int | None, typer.Option(help="Random weight samples (default: config, 1000).")] = None,
        out: Annotated[Path | None, typer.Option(help="Folder for the plot (default: the config's output).")] = None,
    ) -> None:
        """Build a parameterized motion space from the matches of a query (KG04 §4) and store it."""
        from motionweb.flows.commands.cli import request_or_fail, run_command
        from motionweb.flows.commands.requests import SpaceRequest
        from motionweb.flows.space import parameterize as run
        from motionweb.flows.space import plan_space

        request = request_or_fail(SpaceRequest, clip=clip, start=start, end=end, param=param, threshold=threshold,
                                  quantile=quantile, samples=samples, out=str(out) if out else None)
        cfg = config_or_fail(config)

        def work() -> dict:
            plan_space(cfg, request)
            return run.fn(cfg, request)  # in this process, without Prefect (flows/runtime/lazy_prefect.py)

        run_command("parameterize", {"store": cfg.store.path, "request": request.wire()}, work, lambda res: typer.echo(
            f"space {res['id']}: {len(res['examples'])} examples, {res['samples']} samples of {res['param']} "
            f"(ε = {res['epsilon']:.4g}) in {res['timings']['total_s']:.1f} s; plot {res['files'][0]}"), strip=True)

    @app.command()
    def synthesize(
        space: Annotated[str, typer.Argument(help="Space id (or a unique prefix) from `motionweb parameterize`.")],
        target: Annotated[str, typer.Option(help="Target parameter, comma separated (metres), e.g. 0.3,1.2,0.5.")],
        out: Annotated[Path, typer.Option(help="Output motion: .bvh or .glb (glTF binary).")],
        config: Annotated[Path | None, typer.Option(help="Config naming the store.")] = None,
    ) -> None:
        """Make a motion that hits a target parameter (KG04 §4.3); a target outside is projected.

        With a `motionweb app` running for the config's store, the service answers (same BVH)."""
        t, res = ask_service(fail, config, space, "synthesize", lambda: {"target": parse_target(target)}, out)
        t = t.target
        if res is not None:
            typer.echo(synthesis_line(out, res["frames"], res["achieved"], res["error"], res["outside"], res["service"]))
            return
        import numpy as np
        from motionweb.flows.commands.cli import run_command
        from motionweb.flows.space import load_space, space_info
        from motionweb.store.formats import write_motion

        cfg = config_or_fail(config)

        def work() -> dict:
            digest, info, _ = space_info(cfg, space)
            if len(t) != info["dim"]:
                raise ValueError(f"--target has {len(t)} values; space parameter {info['param']} has {info['dim']}")
            motion, syn = load_space(cfg, space).synthesize(np.array(t))
            write_motion(motion, out, up=cfg.corpus.up_axis)
            return {"space": digest, "out": str(out), "frames": motion.n_frames,
                    "achieved": [float(v) for v in syn.achieved], "error": float(syn.error), "outside": bool(syn.outside)}

        run_command("synthesize", {"store": cfg.store.path, "space": space, "request": {"target": t}}, work,
                    lambda r: typer.echo(synthesis_line(out, r["frames"], r["achieved"], r["error"], r["outside"])),
                    strip=True)

    @app.command("blend")
    def blend_cmd(
        space: Annotated[str, typer.Argument(help="Space id (or a unique prefix).")],
        weights: Annotated[list[str], typer.Option(help="CLIP=WEIGHT, repeated; weights sum to 1.")],
        out: Annotated[Path, typer.Option(help="Output motion: .bvh or .glb (glTF binary).")],
        config: Annotated[Path | None, typer.Option(help="Config naming the store.")] = None,
    ) -> None:
        """Blend a space's examples with explicit weights (KG04 §4, foot plants held).

        With a `motionweb app` running for the config's store, the service answers (same BVH)."""
        w, res = ask_service(fail, config, space, "blend", lambda: {"weights": parse_weights(weights)}, out)
        w = w.weights
        if res is not None:
            typer.echo(f"wrote {out}: {res['frames']} frames at {res['fps']:g} fps (by the service at {res['service']})")
            return
        from motionweb.flows.commands.cli import run_command
        from motionweb.flows.space import load_space, space_info, weight_vector
        from motionweb.store.formats import write_motion

        cfg = config_or_fail(config)

        def work() -> dict:
            _, info, _ = space_info(cfg, space)
            weight_vector(info["names"], w)  # names and sum, before loading clips
            motion = load_space(cfg, space).blend(w)
            write_motion(motion, out, up=cfg.corpus.up_axis)
            return {"out": str(out), "frames": motion.n_frames, "fps": float(motion.fps)}

        run_command("blend", {"store": cfg.store.path, "space": space, "request": {"weights": w}}, work,
                    lambda r: typer.echo(f"wrote {out}: {r['frames']} frames at {r['fps']:g} fps"), strip=True)
