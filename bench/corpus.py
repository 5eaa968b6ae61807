"""Benchmark: index a ~37,000-frame library into match webs, split by category and unsplit.

KG04 report 50.2 min unsplit and 3.4 min by category for 37,000 frames at 60 Hz. The shared
real data (DeepMimic, /work/shared/data/mocap via store.datasets.mocap_root) holds only ~35 s,
so the benchmark corpus is built in a temp folder from
  * the real clips themselves (DeepMimic .txt, loaded by store.catalog),
  * variations of them written as BVH at 60 Hz: mirrored (left/right swapped and reflected
    across the sagittal plane) and time-warped (smooth non-linear warps, 0.55-1.0x mean speed),
  * the synthetic demo corpus (store.demo) at 60 Hz,
until it holds the target number of frames (counted at 60 Hz). Each run indexes into a fresh
store with the index flow (Prefect + a local Dask cluster, 2 single-threaded worker processes).
Then the growth of wall time and memory with the frames of a single chunk is fitted
(t ~ frames^p).

Ratio measured in the same run: after each index run, the same webs are rebuilt serially in
this process from the stored features (every ``--serial-every``-th pair, scaled up; no Prefect,
Dask or Zarr): "serial s" is that compute alone on one core, and "wall/serial" what the whole
flow costs against it (2 workers with no overhead would give 0.5).

    .venv/bin/python bench/corpus.py [--frames 37000] [--rates 30 60] [--growth 2000 4000 8000 16000 32000]

Peak memory is the largest sum of RSS over this process and its Dask worker processes (the
Prefect ephemeral API server, a separate process, is excluded), sampled every 50 ms.
"""

from __future__ import annotations

import argparse
import math
import os
import shutil
import tempfile
import threading
import time
from dataclasses import replace
from pathlib import Path

os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
os.environ.setdefault("PREFECT_LOGGING_LEVEL", "WARNING")
os.environ.setdefault("PREFECT_LOGGING_TO_API_WHEN_MISSING_FLOW", "ignore")
os.environ.setdefault("DASK_LOGGING__DISTRIBUTED", "error")

import numpy as np
import psutil
from motionweb.flows.config import Config
from motionweb.store.bvh import write_bvh
from motionweb.store.catalog import load_clip, scan_corpus
from motionweb.store.datasets import mocap_root
from motionweb.store.demo.corpus import write_demo_corpus
from motionweb.store.demo.perturb import random_warp, time_warp_clip
from motionweb.store.generations import load_generation
from motionweb.store.kinematics import resample
from motionweb.store.motion import Motion
from motionweb.store.zarr_store import MotionStore

RATE = 60.0


# ------------------------------------------------------------------------------------ corpus
def mirror(motion: Motion, lateral: int) -> Motion:
    """Left/right mirror: swap left_*/right_* joint data, reflect across the sagittal plane.

    Reflection S = diag with -1 on the lateral axis maps a rotation R to S R S, i.e. the quaternion
    vector part v to -S v; root positions are reflected likewise.
    """
    names = [n.lower() for n in motion.skeleton.names]
    swap = list(range(len(names)))
    for i, n in enumerate(names):
        for a, b in (("left", "right"), ("right", "left")):
            if a in n and n.replace(a, b) in names:
                swap[i] = names.index(n.replace(a, b))
    rot = motion.rotations[:, swap].copy()
    sign = -np.ones(3)
    sign[lateral] = 1.0
    rot[..., 1:] *= sign
    root = motion.root_positions.copy()
    root[:, lateral] *= -1
    return replace(motion, rotations=rot, root_positions=root, name=motion.name + "_mirror",
                   source=None, content_hash="", translations={})


def lateral_axis(motion: Motion) -> int:
    """The axis along which left and right joints are separated in the rest pose."""
    names = [n.lower() for n in motion.skeleton.names]
    left = [i for i, n in enumerate(names) if "left" in n]
    right = [names.index(names[i].replace("left", "right")) for i in left
             if names[i].replace("left", "right") in names]
    d = np.abs(motion.skeleton.offsets[left[: len(right)]] - motion.skeleton.offsets[right]).sum(axis=0)
    return int(np.argmax(d))


def build_corpus(out: Path, target_frames: int, seed: int = 7) -> dict:
    """Real clips + their variations + the synthetic corpus, ~``target_frames`` at 60 Hz."""
    rng = np.random.default_rng(seed)
    cfg = Config.model_validate({"corpus": {"length_unit": "m"}})
    real = scan_corpus(mocap_root(), cfg.corpus)
    out.mkdir(parents=True, exist_ok=True)
    for urdf in mocap_root().rglob("humanoid.urdf"):  # DeepMimic clips find it at ../humanoid.urdf
        shutil.copy(urdf, out / "humanoid.urdf")
    frames = 0
    n_real = n_var = n_syn = 0
    motions = []
    for e in real.entries:
        cat = "dm-" + e.name.removeprefix("humanoid3d_")
        (out / cat).mkdir(parents=True, exist_ok=True)
        shutil.copy(e.abs_path, out / cat / Path(e.path).name)
        frames += round(e.duration * RATE) + 1
        n_real += 1
        m = load_clip(e, cfg.corpus)
        motions.append((cat, resample(m, RATE) if abs(m.fps - RATE) > 1e-9 else m))
    half = target_frames // 2
    speeds = [0.9, 0.75, 0.6, 1.0, 0.8, 0.65, 0.55, 0.85, 0.7]
    k = 0
    while frames < half:
        cat, m = motions[k % len(motions)]
        level = k // len(motions)
        v = mirror(m, lateral_axis(m)) if level % 2 else m
        s = speeds[level % len(speeds)]
        n_out = max(8, round((m.n_frames - 1) / s) + 1)
        if n_out != m.n_frames:
            v = time_warp_clip(v, random_warp(n_out, m.n_frames, rng, (0.45 * s, 1.6 * s)))
        write_bvh(replace(v, fps=RATE), out / cat / f"{cat}_v{level:02d}.bvh")
        frames += v.n_frames
        n_var += 1
        k += 1
    per_clip = 240
    variants = max(1, math.ceil((target_frames - frames) / (9 * per_clip)))
    syn = Path(tempfile.mkdtemp(prefix="syn-", dir=out.parent))
    for p in write_demo_corpus(syn, seed=seed, variants_per_category=variants, fps=RATE):
        dst = out / p.parent.name
        dst.mkdir(exist_ok=True)
        shutil.move(p, dst / p.name)
        n_syn += 1
    shutil.rmtree(syn)
    cat = scan_corpus(out, cfg.corpus)
    total = sum(round(e.duration * RATE) + 1 for e in cat.entries)
    return {"clips": len(cat.entries), "frames60": total, "real": n_real, "variations": n_var,
            "synthetic": n_syn, "categories": len(cat.by_category()), "errors": len(cat.errors),
            "entries": cat.entries}


def subset(corpus: Path, entries, frames: int, out: Path, seed: int = 0) -> int:
    """Copy clips (seeded order) into ``out`` until they hold ``frames`` frames at 60 Hz."""
    order = np.random.default_rng(seed).permutation(len(entries))
    total = 0
    for i in order:
        e = entries[i]
        dst = out / e.path
        dst.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(corpus / e.path, dst)
        total += round(e.duration * RATE) + 1
        if total >= frames:
            break
    return total


# ------------------------------------------------------------------------------------ runs
class PeakRSS:
    """Peak of the summed RSS of this process and its children, Prefect's server excluded."""

    def __init__(self, interval: float = 0.05):
        self.interval, self.peak, self._stop = interval, 0, threading.Event()
        self._skip: set[int] = set()

    def _sample(self) -> int:
        me = psutil.Process()
        total = me.memory_info().rss
        for c in me.children(recursive=True):
            try:
                if c.pid in self._skip:
                    continue
                if any("uvicorn" in a or "prefect" in a for a in c.cmdline()):
                    self._skip.add(c.pid)
                    continue
                total += c.memory_info().rss
            except psutil.Error:
                pass
        return total

    def _run(self) -> None:
        while not self._stop.is_set():
            self.peak = max(self.peak, self._sample())
            time.sleep(self.interval)

    def __enter__(self) -> PeakRSS:  # noqa: PYI034
        self.peak = self._sample()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()


def rates_for(rate: float) -> list[float]:
    """KG04 §3.2 ladder: 10 Hz, 20 Hz, then the working rate."""
    return sorted({10.0, 20.0, float(rate)})


def serial_compute_s(store: Path, every: int) -> float:
    """Seconds to rebuild every ``every``-th web of the store's current generation in this
    process, scaled to all its pairs: the web computation alone (operands read and prepared
    beforehand, compiled kernels warmed up), the baseline the flow's wall time is compared with."""
    from motionweb.flows.workers import clip_operands
    from motionweb.tasks.matchweb.build import build_web_operands

    gen = load_generation(MotionStore(str(store)))
    cfg = Config.model_validate(gen.config)
    fdig = gen.params["features"]
    webs = sorted({w["key"]: w for w in gen.webs}.values(), key=lambda w: w["key"])
    jobs = [(clip_operands(str(store), w["a_sha"], fdig), clip_operands(str(store), w["b_sha"], fdig), w["self"])
            for w in webs[::every]]
    build_web_operands(*jobs[0][:2], cfg.matchweb, jobs[0][2])  # warm-up (compiled kernels load)
    t = time.perf_counter()
    for oa, ob, self_pair in jobs:
        build_web_operands(oa, oa if self_pair else ob, cfg.matchweb, self_pair)
    clip_operands.cache_clear()
    return (time.perf_counter() - t) * len(webs) / len(jobs)


def run_index(corpus: Path, store: Path, rate: float, chunk_by: str, workers: int) -> dict:
    from motionweb.flows.index import index_library

    cfg = Config.model_validate({
        "corpus": {"path": str(corpus), "length_unit": "m"},
        "features": {"rates": rates_for(rate)},
        "store": {"path": str(store)},
        "dask": {"n_workers": workers, "processes": True},
        "index": {"chunk_by": chunk_by},
    })
    t = time.perf_counter()
    with PeakRSS() as mem:
        s = index_library(cfg)
    s["call_s"] = time.perf_counter() - t
    s["peak_gb"] = mem.peak / 1e9
    chunks = {c["name"]: c["frames"] for c in load_generation(MotionStore(str(store))).chunks}
    s["max_chunk_frames"] = max(chunks.values()) if chunks else 0
    return s


def fit_exponent(x: list[float], y: list[float]) -> float:
    """Slope of log y against log x (least squares)."""
    lx, ly = np.log(np.asarray(x, float)), np.log(np.asarray(y, float))
    return float(np.polyfit(lx, ly, 1)[0])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=37000, help="corpus size in frames at 60 Hz")
    ap.add_argument("--rates", type=float, nargs="+", default=[30.0, 60.0])
    ap.add_argument("--modes", nargs="+", default=["category", "none"])
    ap.add_argument("--growth", type=int, nargs="*", default=[2000, 4000, 8000, 16000, 32000])
    ap.add_argument("--growth-rate", type=float, default=60.0)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--keep", help="keep the temp folder here instead of deleting it")
    ap.add_argument("--serial-every", type=int, default=10, help="sample for the serial baseline")
    args = ap.parse_args()

    from prefect.settings import PREFECT_FLOWS_HEARTBEAT_FREQUENCY, temporary_settings

    work = Path(args.keep or tempfile.mkdtemp(prefix="motionweb-bench-"))
    work.mkdir(parents=True, exist_ok=True)
    t = time.perf_counter()
    info = build_corpus(work / "corpus", args.frames)
    print(f"corpus (built in {time.perf_counter() - t:.1f} s, {work / 'corpus'}): {info['clips']} clips, "
          f"{info['frames60']} frames at 60 Hz, {info['categories']} categories")
    print(f"  = {info['real']} real DeepMimic clips (~35 s) + {info['variations']} mirrored/time-warped "
          f"variations of them + {info['synthetic']} synthetic demo clips; the real data alone is far "
          f"smaller than KG04's 37,000 frames, so the corpus is padded with these")
    print(f"  two skeletons (DeepMimic 13 joints, demo 22): clips are only paired with the same skeleton; "
          f"{os.cpu_count()} cores, {args.workers} Dask worker processes x 1 thread")
    print()
    with temporary_settings({PREFECT_FLOWS_HEARTBEAT_FREQUENCY: None}):
        print(f"{'rate':>5} {'split':>9} {'chunks':>6} {'clips':>5} {'frames':>7} {'max chunk':>9} "
              f"{'pairs':>6} {'chains':>7} {'bridges':>7} {'wall s':>7} {'call s':>7} {'peak GB':>7} "
              f"{'store MB':>8} {'serial s':>8} {'wall/serial':>11}  target")
        n = 0
        for rate in args.rates:
            for mode in args.modes:
                s = run_index(work / "corpus", work / f"store-{n}", rate, mode, args.workers)
                serial = serial_compute_s(work / f"store-{n}", args.serial_every)
                n += 1
                target = "<= 20 s" if mode == "category" else "<= 120 s"
                print(f"{rate:5g} {'category' if mode == 'category' else 'unsplit':>9} {s['chunks']:6d} "
                      f"{s['clips']:5d} {s['frames']:7d} {s['max_chunk_frames']:9d} {s['pairs']:6d} "
                      f"{s['chains']:7d} {s['bridges']:7d} {s['wall_s']:7.1f} {s['call_s']:7.1f} "
                      f"{s['peak_gb']:7.2f} {s['store_bytes'] / 1e6:8.1f} {serial:8.1f} {s['wall_s'] / serial:11.2f}"
                      f"  {target} (KG04 60 Hz: {'3.4' if mode == 'category' else '50.2'} min)", flush=True)
                if s["broken"]:
                    print(f"      broken: {s['broken']}")
        # a rerun with nothing changed (nightly): everything from the cache
        s = run_index(work / "corpus", work / f"store-{n - 1}", args.rates[-1], args.modes[-1], args.workers)
        print(f"rerun, nothing changed: {s['pairs_computed']} pairs computed, {s['pairs_cached']} cached, "
              f"{s['wall_s']:.1f} s")
        if args.growth:
            print()
            print(f"growth: one chunk (unsplit) at {args.growth_rate:g} Hz, frames counted at 60 Hz")
            print(f"{'frames':>7} {'clips':>5} {'pairs':>6} {'cells':>10} {'wall s':>7} {'peak GB':>7}")
            xs, ts, ms = [], [], []
            for g in args.growth:
                sub = work / f"growth-{g}"
                frames = subset(work / "corpus", info["entries"], g, sub)
                s = run_index(sub, work / f"store-g{g}", args.growth_rate, "none", args.workers)
                cells = (s["frames"] * args.growth_rate / RATE) ** 2
                print(f"{frames:7d} {s['clips']:5d} {s['pairs']:6d} {cells:10.3g} {s['wall_s']:7.1f} "
                      f"{s['peak_gb']:7.2f}", flush=True)
                xs.append(frames)
                ts.append(s["wall_s"])
                ms.append(s["peak_gb"])
            if len(xs) >= 2:
                print(f"fitted exponent: wall ~ frames^{fit_exponent(xs, ts):.2f}, "
                      f"peak memory ~ frames^{fit_exponent(xs, ms):.2f} "
                      f"(all-pairs grids would be frames^2; coarse-to-fine keeps fine levels near-linear)")
    if not args.keep:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
