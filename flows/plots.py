"""Figure of one match web over its distance grid, in the style of KG04 Fig. 4 / Fig. 7.

The grid is computed on the fly at the working rate (the finest of ``features.rates``; full
grids are not stored by default, design §4). Drawn over it: the valid region (KG04 §3.1, shaded),
the 1-D local minima (dots), the chains of the web (solid lines) and the bridges (dashed), clip A
on the vertical axis (rows) and clip B on the horizontal axis (columns), in seconds.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from motionweb.flows.config import Config


@dataclass
class WebPlot:
    """What was drawn: the two clips, the working rate, the grid shape and the web's counts."""

    out: str
    clip_a: str
    clip_b: str
    rate: float
    shape: tuple[int, int]
    minima: int
    chains: int
    bridges: int


def draw_web(grid: np.ndarray, minima: np.ndarray, valid: np.ndarray, web, rate: float, out: str | Path,
             title: str = "", label_a: str = "A", label_b: str = "B") -> None:
    """Draw ``grid`` (Fa, Fb) with the valid region, minima, chains and bridges; write ``out``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fa, fb = grid.shape
    finite = np.isfinite(grid)
    shown = np.where(finite, grid, np.nan)
    extent = (-0.5 / rate, (fb - 0.5) / rate, -0.5 / rate, (fa - 0.5) / rate)
    scale = max(fa, fb)
    fig, ax = plt.subplots(figsize=(min(12, 3 + 7 * fb / scale), min(12, 2.5 + 7 * fa / scale)), dpi=110)
    vmax = np.nanpercentile(shown, 95) if finite.any() else 1.0
    im = ax.imshow(shown, origin="lower", cmap="gray", extent=extent, vmin=0, vmax=vmax,
                   interpolation="nearest", aspect="equal")
    fig.colorbar(im, ax=ax, shrink=0.8, label="frame distance (m²)")
    ax.imshow(np.ma.masked_where(~valid, valid.astype(float)), origin="lower", cmap="winter", alpha=0.3,
              extent=extent, interpolation="nearest", aspect="equal")
    mi, mj = np.nonzero(minima)
    ax.plot(mj / rate, mi / rate, ".", ms=2, color="#ffbf00", alpha=0.8, label="1-D local minima")
    for p in range(web.n_paths):
        cells, _ = web.path(p)
        ax.plot(cells[:, 1] / rate, cells[:, 0] / rate, "-", lw=1.8, color="#e8322b",
                label="chains" if p == 0 else None)
    for b in range(web.n_bridges):
        cells, _ = web.bridge(b)
        ax.plot(cells[:, 1] / rate, cells[:, 0] / rate, "--", lw=1.2, color="#3fd1ff",
                label="bridges" if b == 0 else None)
    ax.set_xlabel(f"{label_b} (s)")
    ax.set_ylabel(f"{label_a} (s)")
    ax.set_title(title or f"match web at {rate:g} Hz")
    ax.legend(loc="upper left", fontsize=7, framealpha=0.7)
    fig.tight_layout()
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)
    plt.close(fig)


def plot_web(cfg: Config, clip_a: str, clip_b: str, out: str | Path) -> WebPlot:
    """Compute the web of two catalogued clips (path, stem or file) and draw it to ``out``."""
    from motionweb.store.catalog import load_clip, scan_corpus
    from motionweb.tasks.features import clip_features, point_weights
    from motionweb.tasks.matchweb.build import build_web
    from motionweb.tasks.matchweb.minima import local_minima, mask_self_band, valid_region
    from motionweb.tasks.matchweb.params import self_band

    catalog = scan_corpus(cfg.corpus.path, cfg.corpus)
    ea, eb = catalog.find(clip_a), catalog.find(clip_b)
    if ea.skeleton != eb.skeleton:
        raise ValueError(f"{ea.path} and {eb.path} have different skeletons ({ea.n_joints} and "
                         f"{eb.n_joints} joints); their frames cannot be compared")
    ma, mb = load_clip(ea, cfg.corpus), load_clip(eb, cfg.corpus)
    rates = sorted(float(r) for r in cfg.features.rates)
    up = cfg.corpus.up_axis
    fa = {r: clip_features(ma, r, cfg.features, up=up) for r in rates}
    fb = fa if ea.sha256 == eb.sha256 else {r: clip_features(mb, r, cfg.features, up=up) for r in rates}
    weights = point_weights(ma.skeleton, cfg.features)
    self_pair = ea.sha256 == eb.sha256
    web = build_web(fa, fb, weights, cfg.matchweb.model_copy(update={"keep_grids": True}), self_pair)
    rate = rates[-1]
    grid = web.grid
    g = mask_self_band(grid, self_band(cfg.matchweb, rate)) if self_pair else grid
    minima = local_minima(g)
    valid = valid_region(g, minima, cfg.matchweb.valid_a)
    title = (f"{ea.path} × {eb.path} at {rate:g} Hz: {web.n_paths} chains, {web.n_bridges} bridges"
             + (" (self pair, diagonal band ignored)" if self_pair else ""))
    draw_web(g, minima, valid, web, rate, out, title=title, label_a=ea.name, label_b=eb.name)
    return WebPlot(str(out), ea.path, eb.path, rate, tuple(grid.shape), int(np.count_nonzero(minima)),
                   web.n_paths, web.n_bridges)
