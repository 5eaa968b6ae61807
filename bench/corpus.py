"""Benchmark: index a ~37,000-frame library into match webs, split by category and unsplit.

KG04 report 50.2 min unsplit and 3.4 min by category for 37,000 frames at 60 Hz. The shared
real data (/work/shared/data/mocap via store.datasets.mocap_root: 64 CMU ASF/AMC trials at
120 Hz, ~16,000 frames at 60 Hz, and 15 DeepMimic clips, ~35 s) is smaller, so the benchmark
corpus is built in a temp folder (never in the repository) from
  * the real clips themselves, linked (not copied): CMU trials with their subject's ASF skeleton,
    in categories ``cmu-<manifest category>``; DeepMimic clips in ``dm-<name>``,
  * variations of them written as BVH at 60 Hz: mirrored (left/right swapped and reflected
    across the sagittal plane) and time-warped (smooth non-linear warps, 0.55-1.0x mean speed),
    until real + variations hold half the target,
  * synthetic demo clips (store.demo) at 60 Hz, one per category in turn,
until it holds the target number of frames (counted at 60 Hz). The benchmark stops with an error
(``CorpusError``, exit 1) unless the corpus holds every clip it wrote, each loading, in the
categories asked for, with at least the frames asked for, and unless every index run indexed
every clip with none broken. Each run indexes into a fresh
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
import csv
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
from motionweb.store.demo.corpus import CATEGORIES as DEMO_CATEGORIES
from motionweb.store.demo.corpus import generate_clip, write_clip
from motionweb.store.demo.perturb import random_warp, time_warp_clip
from motionweb.store.formats import find_asf
from motionweb.store.generations import load_generation
from motionweb.store.kinematics import resample
from motionweb.store.motion import Motion
from motionweb.store.zarr_store import MotionStore

RATE = 60.0


# ------------------------------------------------------------------------------------ corpus
class CorpusError(SystemExit):
    """The benchmark did not get the corpus (or index) it asked for: it stops with this message
    (exit status 1), never measures a smaller corpus than it claims."""

    def __init__(self, message: str):
        super().__init__(f"bench: {message}")


def _lr_partner(name: str, names: list[str]) -> int | None:
    """The index of the left/right counterpart of joint ``name`` (lower case) in ``names``:
    ``left``/``right`` anywhere in the name (BVH, demo, DeepMimic) or CMU's ``l``/``r`` prefix
    (``lfemur``/``rfemur``); None when it has none."""
    for a, b in (("left", "right"), ("right", "left")):
        if a in name and name.replace(a, b) in names:
            return names.index(name.replace(a, b))
    if name[:1] in ("l", "r") and ("r" if name[0] == "l" else "l") + name[1:] in names:
        return names.index(("r" if name[0] == "l" else "l") + name[1:])
    return None


def mirror(motion: Motion, lateral: int) -> Motion:
    """Left/right mirror: swap left/right joint data, reflect across the sagittal plane.

    Reflection S = diag with -1 on the lateral axis maps a rotation R to S R S, i.e. the quaternion
    vector part v to -S v; root positions are reflected likewise.
    """
    names = [n.lower() for n in motion.skeleton.names]
    swap = [i if (j := _lr_partner(n, names)) is None else j for i, n in enumerate(names)]
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
    pairs = [(i, j) for i, n in enumerate(names) if (j := _lr_partner(n, names)) is not None and i < j]
    if not pairs:
        raise CorpusError(f"{motion.name}: no left/right joint pairs to mirror")
    left, right = zip(*pairs, strict=True)
    d = np.abs(motion.skeleton.offsets[list(left)] - motion.skeleton.offsets[list(right)]).sum(axis=0)
    return int(np.argmax(d))


def in_metres(motion: Motion) -> Motion:
    """``motion`` with its lengths (offsets, end sites, root and joint translations) in metres, as
    the variations are written (BVH read with the corpus's ``length_unit: m``)."""
    k = motion.metres()
    if k == 1.0:
        return motion
    sk = motion.skeleton
    sk = replace(sk, offsets=sk.offsets * k, end_sites={j: o * k for j, o in sk.end_sites.items()})
    return replace(motion, skeleton=sk, root_positions=motion.root_positions * k, unit="m", scale_to_m=1.0,
                   translations={j: t * k for j, t in motion.translations.items()})


def frames60(duration: float) -> int:
    """Frames of a clip of ``duration`` seconds counted at 60 Hz (how the corpus is sized)."""
    return round(duration * RATE) + 1


def link_clip(src: Path, dst: Path) -> None:
    """Put the real clip ``src`` at ``dst`` as a symbolic link (the shared data are never copied),
    with what it needs to load beside it: an AMC trial its subject's ASF skeleton
    (``store.formats.find_asf``)."""
    dst.parent.mkdir(parents=True, exist_ok=True)
    src = Path(src).resolve()
    dst.symlink_to(src)
    if src.suffix.lower() == ".amc":
        asf = find_asf(src)
        if not (dst.parent / asf.name).exists():
            (dst.parent / asf.name).symlink_to(asf.resolve())


def cmu_categories(root: Path) -> dict[str, str]:
    """Corpus-relative path (under ``root``, the mocap folder) -> category, from cmu/manifest.csv."""
    manifest = root / "cmu" / "manifest.csv"
    if not manifest.is_file():
        return {}
    with manifest.open(newline="") as f:
        return {f"cmu/{row['path']}": row["category"] for row in csv.DictReader(f)}


def real_placement(root: Path, entries) -> list[tuple]:
    """Where each real clip of ``root`` (catalog ``entries``) goes in a benchmark corpus:
    (entry, corpus path, category) for the CMU ASF/AMC trials, ``cmu-<manifest category>/<subject>/``
    (categories from cmu/manifest.csv), and the DeepMimic clips, ``dm-<name>/``. CMU's two BVH
    conversions are left out: one repeats an AMC trial, and neither declares its length unit."""
    cmu = cmu_categories(root)
    placed = []
    for e in entries:
        if e.format == "asfamc":
            if e.path not in cmu:
                raise CorpusError(f"{e.path} has no category in {root / 'cmu' / 'manifest.csv'}")
            cat = "cmu-" + cmu[e.path]
            placed.append((e, f"{cat}/{Path(e.path).parent.name}/{Path(e.path).name}", cat))
        elif e.format == "deepmimic":
            cat = "dm-" + e.name.removeprefix("humanoid3d_")
            placed.append((e, f"{cat}/{Path(e.path).name}", cat))
    return placed


def link_urdf(root: Path, out: Path) -> None:
    """Link DeepMimic's humanoid.urdf into ``out`` (its clips find it at ../humanoid.urdf)."""
    out.mkdir(parents=True, exist_ok=True)
    for urdf in root.rglob("humanoid.urdf"):
        if not (out / "humanoid.urdf").exists():
            (out / "humanoid.urdf").symlink_to(urdf.resolve())


def check_corpus(out: Path, cat, expected: dict[str, str], target_frames: int) -> int:
    """Stop (:class:`CorpusError`) unless the scan of ``out`` found exactly the clips written
    (corpus path -> category in ``expected``), none unreadable, with those categories and at least
    ``target_frames`` frames at 60 Hz; returns the frames."""
    if cat.errors:
        listed = "; ".join(f"{e.path}: {e.reason}" for e in cat.errors[:5])
        raise CorpusError(f"{len(cat.errors)} clips of the corpus in {out} do not load ({listed}"
                          f"{'; ...' if len(cat.errors) > 5 else ''})")
    got = {e.path: e.category for e in cat.entries}
    missing, extra = sorted(set(expected) - set(got)), sorted(set(got) - set(expected))
    if missing or extra:
        raise CorpusError(f"the corpus in {out} holds {len(got)} clips, {len(expected)} were written: "
                          f"missing {missing[:5]}, unexpected {extra[:5]}")
    wrong = sorted(p for p in expected if got[p] != expected[p])
    if wrong:
        raise CorpusError(f"clips labelled with another category than asked: {wrong[:5]}")
    total = sum(frames60(e.duration) for e in cat.entries)
    if total < target_frames:
        raise CorpusError(f"the corpus in {out} holds {total} frames at 60 Hz, fewer than the {target_frames} asked for")
    return total


def build_corpus(out: Path, target_frames: int, seed: int = 7) -> dict:
    """Real clips + their variations + the synthetic corpus, ``target_frames`` at 60 Hz or a clip
    more; stops with :class:`CorpusError` unless the scan finds every clip written, each loading,
    in the categories asked for, with at least ``target_frames`` frames.

    Real clips (CMU ASF/AMC trials with their subject's skeleton, DeepMimic clips) are linked, not
    copied, into ``out``: ``cmu-<category>/<subject>/`` (categories from cmu/manifest.csv) and
    ``dm-<name>/``. CMU's two BVH conversions are left out: one repeats an AMC trial, and neither
    declares its length unit, which the corpus gives as metres for the BVH files written here.
    Cost: one parse of every real clip, O(real bytes), plus writing the variations and synthetic
    clips, O(target_frames)."""
    rng = np.random.default_rng(seed)
    cfg = Config.model_validate({"corpus": {"length_unit": "m"}})
    root = mocap_root()
    if not root.is_dir():
        raise CorpusError(f"no real motion capture at {root} (set $MOTIONWEB_MOCAP)")
    real = scan_corpus(root, cfg.corpus)
    if real.errors:
        raise CorpusError(f"{len(real.errors)} clips of {root} do not load: "
                          + "; ".join(f"{e.path}: {e.reason}" for e in real.errors[:5]))
    link_urdf(root, out)
    expected: dict[str, str] = {}  # corpus path -> category
    frames = 0
    n_real = n_var = n_syn = 0
    motions = []
    placed = real_placement(root, real.entries)
    skipped = len(real.entries) - len(placed)
    for e, rel, cat in placed:
        link_clip(Path(e.abs_path), out / rel)
        expected[rel] = cat
        frames += frames60(e.duration)
        n_real += 1
        m = in_metres(load_clip(e, cfg.corpus))
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
        rel = f"{cat}/{Path(m.name).stem}_v{level:02d}.bvh"
        write_bvh(replace(v, fps=RATE), out / rel)
        expected[rel] = cat
        frames += v.n_frames
        n_var += 1
        k += 1
    # synthetic clips, one per category in turn, until the corpus holds the frames asked for
    v = 0
    while frames < target_frames:
        for cat in DEMO_CATEGORIES:
            if frames >= target_frames:
                break
            motion, truth = generate_clip(cat, v, seed, RATE)
            path = write_clip(motion, truth, out / cat / f"{cat}_{v:02d}")
            expected[path.relative_to(out).as_posix()] = cat
            frames += motion.n_frames
            n_syn += 1
        v += 1
    cat = scan_corpus(out, cfg.corpus)
    total = check_corpus(out, cat, expected, target_frames)
    return {"clips": len(cat.entries), "frames60": total, "real": n_real, "variations": n_var,
            "synthetic": n_syn, "categories": len(cat.by_category()), "errors": len(cat.errors),
            "skipped_real": skipped, "entries": cat.entries}


def subset(corpus: Path, entries, frames: int, out: Path, seed: int = 0) -> tuple[int, int]:
    """Link clips (seeded order) of ``corpus`` into ``out`` until they hold ``frames`` frames at
    60 Hz (an AMC trial with its skeleton); (frames, clips). Stops with :class:`CorpusError` when
    the corpus is too small."""
    order = np.random.default_rng(seed).permutation(len(entries))
    total = 0
    for n, i in enumerate(order, 1):
        e = entries[i]
        link_clip(corpus / e.path, out / e.path)
        total += frames60(e.duration)
        if total >= frames:
            return total, n
    raise CorpusError(f"a subset of {frames} frames asked of a corpus of {total} frames ({corpus})")


# ------------------------------------------------------------------------------------ runs
class PeakRSS:
    """Peak of the summed RSS of ``root`` (default: this process) and its children, Prefect's
    server excluded. The RSS is sampled every ``interval`` seconds, the list of children every
    ``refresh`` seconds: listing them reads every process's ``/proc/PID/stat`` (psutil's
    ``children``), which every 50 ms took ~5% of a core from the run it measured."""

    def __init__(self, interval: float = 0.05, root: psutil.Process | None = None, refresh: float = 1.0):
        self.interval, self.refresh, self.peak, self._stop = interval, refresh, 0, threading.Event()
        self._skip: set[int] = set()
        self.root = root
        self._kids: list[psutil.Process] = []
        self._listed = -math.inf

    def _children(self, me: psutil.Process) -> list[int]:
        """The RSS of each child process of ``me``, Prefect's server excluded."""
        now = time.monotonic()
        if now - self._listed >= self.refresh:
            self._listed = now
            try:
                kids = me.children(recursive=True)
            except psutil.Error:
                kids = []
            self._kids = []
            for c in kids:
                try:
                    if c.pid not in self._skip and any("uvicorn" in a or "prefect" in a for a in c.cmdline()):
                        self._skip.add(c.pid)
                except psutil.Error:
                    continue
                if c.pid not in self._skip:
                    self._kids.append(c)
        out = []
        for c in self._kids:
            try:
                out.append(c.memory_info().rss)
            except psutil.Error:
                pass
        return out

    def _sample(self) -> int:
        me = self.root or psutil.Process()
        try:
            total = me.memory_info().rss
        except psutil.Error:
            return 0
        return total + sum(self._children(me))

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
    from motionweb.flows.runtime.workers import clear_operands, clip_operands
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
    clear_operands()
    return (time.perf_counter() - t) * len(webs) / len(jobs)


def run_index(corpus: Path, store: Path, rate: float, chunk_by: str, workers: int,
              expect_clips: int | None = None) -> dict:
    """Index ``corpus`` into ``store`` with the index flow; stops with :class:`CorpusError` when a
    clip or pair is broken or (``expect_clips``) the run indexed another number of clips."""
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
    if s["broken"]:
        raise CorpusError(f"indexing {corpus} left {len(s['broken'])} broken: {s['broken'][:5]}")
    if expect_clips is not None and s["clips"] != expect_clips:
        raise CorpusError(f"indexing {corpus} indexed {s['clips']} clips, {expect_clips} were asked for")
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
    print(f"  = {info['real']} real clips (CMU ASF/AMC with their skeletons, DeepMimic; {info['skipped_real']} "
          f"CMU BVH conversions left out) + {info['variations']} mirrored/time-warped variations of them + "
          f"{info['synthetic']} synthetic demo clips; the real data alone is smaller than KG04's 37,000 frames")
    print(f"  several skeletons (CMU subjects, DeepMimic, demo): clips are only paired with the same skeleton; "
          f"{os.cpu_count()} cores, {args.workers} Dask worker processes x 1 thread")
    print()
    with temporary_settings({PREFECT_FLOWS_HEARTBEAT_FREQUENCY: None}):
        print(f"{'rate':>5} {'split':>9} {'chunks':>6} {'clips':>5} {'frames':>7} {'max chunk':>9} "
              f"{'pairs':>6} {'chains':>7} {'bridges':>7} {'wall s':>7} {'call s':>7} {'peak GB':>7} "
              f"{'store MB':>8} {'serial s':>8} {'wall/serial':>11}  target")
        n = 0
        for rate in args.rates:
            for mode in args.modes:
                s = run_index(work / "corpus", work / f"store-{n}", rate, mode, args.workers, info["clips"])
                serial = serial_compute_s(work / f"store-{n}", args.serial_every)
                n += 1
                target = "<= 20 s" if mode == "category" else "<= 120 s"
                print(f"{rate:5g} {'category' if mode == 'category' else 'unsplit':>9} {s['chunks']:6d} "
                      f"{s['clips']:5d} {s['frames']:7d} {s['max_chunk_frames']:9d} {s['pairs']:6d} "
                      f"{s['chains']:7d} {s['bridges']:7d} {s['wall_s']:7.1f} {s['call_s']:7.1f} "
                      f"{s['peak_gb']:7.2f} {s['store_bytes'] / 1e6:8.1f} {serial:8.1f} {s['wall_s'] / serial:11.2f}"
                      f"  {target} (KG04 60 Hz: {'3.4' if mode == 'category' else '50.2'} min)", flush=True)
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
                frames, n_clips = subset(work / "corpus", info["entries"], g, sub)
                s = run_index(sub, work / f"store-g{g}", args.growth_rate, "none", args.workers, n_clips)
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
