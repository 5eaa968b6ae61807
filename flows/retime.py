"""Physics-based retiming flow (design §8): a thin Prefect wrapper over ``tasks.retime``;
``retime_flow.fn(...)`` runs the same work without Prefect (flows/runtime/lazy_prefect.py)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from motionweb.flows.config import Config
from motionweb.flows.runtime.lazy_prefect import call, flow, task
from motionweb.store.formats import read_motion, write_motion
from motionweb.store.motion import Motion
from motionweb.tasks.retime import (
    RetimeParams,
    RetimePlan,
    RetimeResult,
    flight_intervals,
    prepare,
    report,
    retime_plan,
)


def load_clip(path: str | Path, cfg: Config) -> tuple[Motion, object | None]:
    """The clip and, for DeepMimic clips, the URDF humanoid with its real masses."""
    motion = read_motion(path, unit=cfg.corpus.length_unit, scale_to_m=cfg.corpus.scale_to_m)
    return motion, clip_humanoid(path)


def clip_humanoid(path: str | Path) -> object | None:
    """The URDF humanoid (real masses) of a DeepMimic clip (``.txt``); None for other formats."""
    if Path(path).suffix.lower() != ".txt":
        return None
    from motionweb.store.deepmimic import default_urdf, read_humanoid_urdf

    return read_humanoid_urdf(default_urdf(path))


@task()
def prepare_task(motion: Motion, opts: RetimeParams, up_axis: str, gravity: np.ndarray | None,
                 mass: dict[str, float], humanoid: object | None, intervals: dict | None,
                 weight_factors: dict[str, float]) -> RetimePlan:
    return prepare(motion, opts, up_axis=up_axis, gravity=gravity, mass=mass, humanoid=humanoid, contact_intervals=intervals,
                   weight_factors=weight_factors)


@task()
def retime_task(plan: RetimePlan, duration: float, keytimes: list[tuple[float, float]], opts: RetimeParams
                ) -> tuple[Motion, RetimeResult]:
    return retime_plan(plan, duration, keytimes, opts)


def plot_retiming(plan: RetimePlan, res: RetimeResult, out_dir: str | Path, n_polygons: int = 6) -> list[Path]:
    """p(t) against linear timing, and polygons with the solution's (p̈, ṗ²) at chosen frames."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    m = plan.motion
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.plot(res.t, res.p, label="p(t) retimed")
    ax.plot(res.t, res.t * m.duration / res.t[-1], "--", label="linear")
    for s0, s1 in [(f["source"][0], f["source"][1]) for f in report_flights(plan, res)]:
        ax.axhspan(s0, s1, color="0.9")
    ax.set_xlabel("output time (s)")
    ax.set_ylabel("source time (s)")
    ax.legend()
    paths = [out_dir / "timing.png"]
    fig.savefig(paths[0], dpi=100)
    plt.close(fig)
    idx = np.linspace(0, len(res.t) - 1, n_polygons).round().astype(int)
    fig, axes = plt.subplots(1, n_polygons, figsize=(3 * n_polygons, 3))
    for ax, k in zip(np.atleast_1d(axes), idx, strict=True):
        i = int(np.clip(np.rint(res.p[k] * m.fps), 0, m.n_frames - 1))
        v = plan.polygons.vertices[i]
        if len(v):
            vv = np.vstack([v, v[:1]])
            ax.fill(vv[:, 0], vv[:, 1], alpha=0.3)
        ax.plot([0], [1], "k+", label="original")
        ax.plot([res.pdd[k]], [res.pd[k] ** 2], "ro", label="retimed")
        ax.set_title(f"src frame {i}{' (infeasible)' if plan.polygons.infeasible[i] else ''}", fontsize=8)
        ax.set_xlabel("p̈")
        ax.set_ylabel("ṗ²")
    paths.append(out_dir / "polygons.png")
    fig.tight_layout()
    fig.savefig(paths[1], dpi=100)
    plt.close(fig)
    return paths


def report_flights(plan: RetimePlan, res: RetimeResult) -> list[dict]:
    return [{"source": [a, b]} for a, b in flight_intervals(plan.contacts.active, plan.motion.fps)]


@flow(name="retime")
def retime_flow(input_path: str, cfg: Config, out: str, duration: float | None = None,
                keytimes: list[tuple[float, float]] | None = None, gravity: list[float] | None = None,
                mass: dict[str, float] | None = None, objective: str | None = None,
                plot_dir: str | None = None, weight_factors: dict[str, float] | None = None) -> dict:
    """Retime one clip: write the BVH, a JSON report beside it, and optional plots (design §8,
    MPS06 §3). ``mass`` and ``weight_factors`` (the CLI's ``--weight``): per joint name, a
    multiplier of the body's mass, or of its weight alone."""
    motion, humanoid = load_clip(input_path, cfg)
    opts = cfg.retime if objective is None else cfg.retime.model_copy(
        update={"spline": cfg.retime.spline.model_copy(update={"objective": objective})})
    intervals = cfg.retime.contacts.intervals.get(motion.name) or None
    plan = call(prepare_task, motion, opts, cfg.corpus.up_axis, None if gravity is None else np.asarray(gravity, float), mass or {},
                        humanoid, intervals, weight_factors or {})
    keytimes = list(keytimes or [])
    total = duration if duration is not None else motion.duration
    retimed, res = call(retime_task, plan, total, keytimes, opts)
    out_path = Path(out)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    write_motion(retimed, out_path, up=cfg.corpus.up_axis)
    rep = report(plan, res)
    rep["output"] = str(out_path)
    if plot_dir:
        rep["plots"] = [str(p) for p in plot_retiming(plan, res, plot_dir)]
    out_path.with_suffix(".json").write_text(json.dumps(rep, indent=1))
    return rep
