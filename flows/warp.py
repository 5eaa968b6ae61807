"""The guided time warp flow (design §7, HDP07 §3): load, warp, write BVH and a warp-curve plot.

Everything here is a thin shell over :mod:`tasks.guided_warp`; :func:`plan_warp` does all the
checks (so the CLI can report bad input before a flow run starts) and :func:`run_warp` is the
whole computation as a plain function.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from motionweb.flows.commands.requests import WarpRequest
from motionweb.flows.config import Config, load_motion
from motionweb.flows.runtime.lazy_prefect import call, flow, task
from motionweb.store.motion import Motion
from motionweb.tasks.guided_warp import (
    WarpParams,
    WarpResult,
    check_compatible,
    guided_warp,
    linear_warp,
    playback_speed,
    reduce_to_compression,
)
from motionweb.tasks.retime import RetimeError, RetimeParams, clip_contacts, inner_flights


@dataclass(frozen=True)
class WarpPlan:
    """A checked request: the motions, output length m (None: unconstrained), keytimes in frames;
    the up axis and the retime section's contact settings the summary's flight phases use."""

    motion: Motion
    reference: Motion | None
    n_out: int | None
    keytimes: tuple[tuple[float, float], ...]
    config: WarpParams
    up_axis: str
    contact_params: RetimeParams


def plan_warp(config: Config, request: WarpRequest) -> WarpPlan:
    """Load and check a request; raises ValueError (or MotionFormatError) naming the problem."""
    motion = load_motion(request.input, config)
    reference = load_motion(request.reference, config) if request.reference else None
    return plan_motions(config, request, motion, reference)


def plan_motions(config: Config, request: WarpRequest, motion: Motion, reference: Motion | None) -> WarpPlan:
    """:func:`plan_warp` of motions already read (``request.input`` / ``reference`` are only
    names then; the warp sessions of ``motionweb app`` read them from the index)."""
    cfg = config.warp
    if request.skip is not None:
        cfg = cfg.model_copy(update={"skip": request.skip})
    if reference is not None:
        check_compatible(motion, reference)
    fps = motion.fps
    if request.duration is not None:  # exactly one of the three, > 0: checked by WarpRequest
        n_out = round(request.duration * fps) + 1
    elif request.frames is not None:
        n_out = int(request.frames)
    else:
        n_out = None
    keys = tuple((float(i) * fps, float(o) * fps) for i, o in request.keytimes)
    reduce_to_compression(motion.n_frames, n_out, keys, cfg.skip, request.backward)
    return WarpPlan(motion, reference, n_out, keys, cfg, config.corpus.up_axis, config.retime)


def solve(plan: WarpPlan, fast: bool = False, backward: bool = False, scores: dict | None = None) -> WarpResult:
    """The guided warp of a checked plan with the config's parameters (``scores``: the local
    scores kept by the caller for this input and reference, see :func:`guided_warp`)."""
    return guided_warp(plan.motion, plan.reference, n_out=plan.n_out, keytimes=plan.keytimes,
                       params=plan.config, fast=fast, backward=backward, scores=scores)


def plot_warp(result: WarpResult, fps: float, path: str | Path, linear: WarpResult | None = None,
              title: str = "") -> None:
    """HDP07 Fig. 2 style: input time against output time, guided vs linear, keytimes marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_t = np.arange(result.n_out) / fps
    fig, ax = plt.subplots(figsize=(6.4, 4.8), dpi=100)
    if linear is not None:
        ax.plot(np.arange(linear.n_out) / fps, linear.times / fps, "--", color="0.5", label="linear warp")
    ax.plot(out_t, result.raw_times / fps, ".", ms=2.5, color="tab:orange", alpha=0.6, label="discrete path")
    ax.plot(out_t, result.times / fps, "-", color="tab:blue", lw=1.8, label="guided warp")
    keys = np.array(result.keytimes)
    ax.plot(keys[:, 1] / fps, keys[:, 0] / fps, "o", ms=7, mfc="none", mec="k", mew=1.5, label="keytimes")
    ax.set_xlabel("output time (s)")
    ax.set_ylabel("input time (s)")
    ax.set_title(title or "guided time warp (HDP07)")
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def flight_phases(motion: Motion, result: WarpResult, opts: RetimeParams, up_axis: str) -> list[dict[str, float]]:
    """What the warp did to each flight phase of the input, no foot on the ground as the physics
    retiming detects contacts (``opts``, MPS06 §3.2): its start in the input (``start_s``), source and
    output seconds and their ratio (HDP07 §4.1's preservation measure; 1 keeps the flight's speed).
    Empty for a clip of unknown length unit or one whose feet cannot be found."""
    if motion.scale_to_m is None:
        return []
    try:
        contacts = clip_contacts(motion, opts, up="xyz".index(up_axis))
    except (ValueError, RetimeError):
        return []
    out = []
    for a, b in inner_flights(contacts.active, motion.fps):
        ratio = 1.0 / playback_speed(result.times, a * motion.fps, b * motion.fps)
        out.append({"start_s": a, "source_s": b - a, "output_s": (b - a) * ratio, "ratio": ratio})
    return out


def write_outputs(plan: WarpPlan, result: WarpResult, request: WarpRequest) -> dict[str, Any]:
    """Write the warped BVH (input skeleton, channel orders, unit) and the optional plot."""
    from motionweb.store.formats import write_motion

    out = Path(request.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    assert result.motion is not None
    write_motion(result.motion, out, up=plan.up_axis)
    if request.plot:
        lin = None
        if result.keytimes and not request.unconstrained and not request.backward:
            lin = linear_warp(plan.motion, result.n_out, plan.keytimes, resample_motion=False)
        Path(request.plot).parent.mkdir(parents=True, exist_ok=True)
        plot_warp(result, plan.motion.fps, request.plot, lin,
                  title=f"{Path(request.input).name}: {plan.motion.n_frames} -> {result.n_out} frames")
    fps = plan.motion.fps
    return {
        "input": request.input, "reference": request.reference or request.input, "out": str(out),
        "plot": request.plot, "input_frames": plan.motion.n_frames, "output_frames": result.n_out,
        "input_s": plan.motion.duration, "output_s": (result.n_out - 1) / fps, "cost": result.cost,
        "upsample": result.upsample, "backward": result.backward, "heuristic": result.heuristic,
        "keytimes_s": [(i / fps, o / fps) for i, o in result.keytimes],
        "flights": flight_phases(plan.motion, result, plan.contact_params, plan.up_axis),
        "timings": result.timings,
    }


def run_warp(config: Config, request: WarpRequest) -> dict[str, Any]:
    """The whole warp as a plain function (what the flow runs); returns a summary dict."""
    t0 = time.perf_counter()
    plan = plan_warp(config, request)
    result = solve(plan, request.fast, request.backward)
    summary = write_outputs(plan, result, request)
    summary["wall_s"] = time.perf_counter() - t0
    return summary


plan_task = task(name="plan-warp", no_cache=True)(plan_warp)
solve_task = task(name="guided-warp", no_cache=True)(solve)
write_task = task(name="write-warp", no_cache=True)(write_outputs)


@flow(name="guided-warp", validate_parameters=False)
def warp(config: Config, request: WarpRequest) -> dict[str, Any]:
    """Guided time warp of one clip (HDP07 §3): plan, solve, write BVH and plot; returns a summary."""
    t0 = time.perf_counter()
    plan = call(plan_task, config, request)
    result = call(solve_task, plan, request.fast, request.backward)
    summary = call(write_task, plan, result, request)
    summary["wall_s"] = time.perf_counter() - t0
    return summary


def format_summary(summary: dict[str, Any]) -> str:
    """A few lines for the terminal."""
    t = summary["timings"]
    keys = ", ".join(f"{i:.3g}s->{o:.3g}s" for i, o in summary["keytimes_s"])
    return "\n".join([
        (f"wrote {summary['out']} ({summary['input_frames']} -> {summary['output_frames']} frames, "
        f"{summary['input_s']:.3f}s -> {summary['output_s']:.3f}s)"),
        f"keytimes {keys}; upsample x{summary['upsample']}; cost {summary['cost']:.4g}"
        + ("; heuristic" if summary["heuristic"] else ""),
    ] + [f"  flight {f['source_s']:.3f} s -> {f['output_s']:.3f} s (x{f['ratio']:.2f})" for f in summary["flights"]] + [
        "timings " + ", ".join(f"{k} {v * 1000:.1f} ms" for k, v in t.items()),
    ] + ([f"plot {summary['plot']}"] if summary.get("plot") else []))


__all__ = ["WarpPlan", "WarpRequest", "format_summary", "load_motion", "plan_motions", "plan_warp", "plot_warp",
           "run_warp", "solve", "warp", "write_outputs"]
