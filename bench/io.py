"""Benchmark: load + forward kinematics of every clip under the real-data folder.

Prints MB/s parsed and joint-frames/s of FK for our readers; then the real CMU files (ASF/AMC and
cgspeed BVH) and the same clips written as BVH, parsed by our reader and, in the same run, by
`bvhio` and by `pymotion` (PyPI ``upc-pymotion``: its BVH reader, and its FK), as ratios (both are
in the ``bench`` extra). Target: >= 30 MB/s parsing and >= 10x bvhio.

    .venv/bin/python bench/io.py [--repeat 3] [--upsample 120]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from motionweb.store.bvh import read_bvh, write_bvh
from motionweb.store.datasets import mocap_root
from motionweb.store.formats import is_clip, read_motion
from motionweb.store.kinematics import forward_kinematics, resample

from bench.timing import best_of


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--upsample", type=float, default=120.0, help="rate of the BVH copies (CMU files are 120 Hz)")
    args = ap.parse_args()
    root = mocap_root()
    files = sorted(p for p in root.rglob("*") if p.is_file() and is_clip(p))
    if not files:
        raise SystemExit(f"no clips under {root} (set MOTIONWEB_MOCAP)")
    motions = [read_motion(p) for p in files]  # warm-up (numba compile, page cache)
    size = sum(p.stat().st_size for p in files)
    t_load = best_of(lambda: [read_motion(p) for p in files], args.repeat)[0]
    jf = sum(m.n_frames * m.skeleton.n_joints for m in motions)
    t_fk = best_of(lambda: [forward_kinematics(m) for m in motions], args.repeat)[0]
    print(f"real clips: {len(files)} files under {root}, {size / 1e6:.2f} MB, "
          f"{sum(m.n_frames for m in motions)} frames")
    print(f"  load (native format)   {size / 1e6 / t_load:8.1f} MB/s   ({t_load * 1e3:.1f} ms)")
    print(f"  forward kinematics     {jf / t_fk / 1e6:8.2f} M joint-frames/s")

    cmu_formats(root, args.repeat)

    import bvhio

    with tempfile.TemporaryDirectory() as tmp:
        bvh_files = []
        for p, m in zip(files, motions, strict=True):
            out = Path(tmp) / (p.stem + ".bvh")
            write_bvh(resample(m, args.upsample), out)
            bvh_files.append(out)
        # bvhio needs CHANNELS on every joint: copies of skeletons with fixed joints (CMU ASF
        # bones without dof, written with 0 channels) are left out of the comparison
        readable = []
        for p in bvh_files:
            try:
                bvhio.readAsBvh(str(p))
                readable.append(p)
            except SyntaxError:
                pass
        if len(readable) < len(bvh_files):
            print(f"(bvhio cannot read {len(bvh_files) - len(readable)} of the {len(bvh_files)} copies: "
                  f"joints with 0 channels; compared on the other {len(readable)})")
        bvh_files = readable
        bsize = sum(p.stat().st_size for p in bvh_files)
        bm = [read_bvh(p) for p in bvh_files]
        t_ours = best_of(lambda: [read_bvh(p) for p in bvh_files], args.repeat)[0]
        t_fk2 = best_of(lambda: [forward_kinematics(m) for m in bm], args.repeat)[0]
        t_bvhio = best_of(lambda: [bvhio.readAsBvh(str(p)) for p in bvh_files], max(1, args.repeat // 2))[0]
        jf2 = sum(m.n_frames * m.skeleton.n_joints for m in bm)
        print(f"BVH copies at {args.upsample:g} Hz: {len(bvh_files)} files, {bsize / 1e6:.2f} MB, "
              f"{sum(m.n_frames for m in bm)} frames")
        print(f"  motionweb read_bvh     {bsize / 1e6 / t_ours:8.1f} MB/s   ({t_ours * 1e3:.1f} ms)")
        print(f"  bvhio.readAsBvh        {bsize / 1e6 / t_bvhio:8.1f} MB/s   ({t_bvhio * 1e3:.1f} ms)")
        print(f"  ratio (bvhio / ours)   {t_bvhio / t_ours:8.1f} x   (target >= 10x)")
        print(f"  read + FK              {bsize / 1e6 / (t_ours + t_fk2):8.1f} MB/s, "
              f"FK {jf2 / t_fk2 / 1e6:.2f} M joint-frames/s")


def pymotion_read_fk(path: Path) -> np.ndarray:
    """pymotion's BVH reader and FK: global joint positions (F, J, 3)."""
    from pymotion.io.bvh import BVH
    from pymotion.ops.skeleton import fk

    bvh = BVH()
    bvh.load(str(path))
    rots, pos, parents, offsets, _, _ = bvh.get_data()
    return fk(rots, pos[:, 0], offsets, parents)[0]


def cmu_formats(root: Path, repeat: int) -> None:
    """MB/s on the shared CMU files in their own formats: AMC (ours), BVH (ours, bvhio, pymotion)."""
    import bvhio

    cmu = root / "cmu"
    amc = sorted(cmu.rglob("*.amc"))
    bvh = sorted(cmu.rglob("*.bvh"))
    if not amc or not bvh:
        print(f"no CMU AMC / BVH files under {cmu}")
        return
    for files, label in ((amc, "AMC"), (bvh, "BVH")):
        size = sum(p.stat().st_size for p in files)
        [read_motion(p) for p in files]
        t_read = best_of(lambda files=files: [read_motion(p) for p in files], repeat)[0]
        t_fk = best_of(lambda files=files: [forward_kinematics(read_motion(p)) for p in files], repeat)[0]
        print(f"CMU {label}: {len(files)} files, {size / 1e6:.2f} MB")
        print(f"  motionweb read         {size / 1e6 / t_read:8.1f} MB/s   read + FK {size / 1e6 / t_fk:8.1f} MB/s")
        if label != "BVH":
            continue
        t_bvhio = best_of(lambda: [bvhio.readAsBvh(str(p)) for p in files], max(1, repeat // 2))[0]
        from pymotion.io.bvh import BVH

        t_pm = best_of(lambda: [BVH().load(str(p)) for p in files], max(1, repeat // 2))[0]
        t_pm_fk = best_of(lambda: [pymotion_read_fk(p) for p in files], max(1, repeat // 2))[0]
        ours = read_motion(files[0])
        np.testing.assert_allclose(pymotion_read_fk(files[0]), forward_kinematics(ours)[0], atol=1e-3)
        print(f"  bvhio.readAsBvh        {size / 1e6 / t_bvhio:8.1f} MB/s   ours {t_bvhio / t_read:6.1f}x faster")
        print(f"  pymotion BVH.load      {size / 1e6 / t_pm:8.1f} MB/s   ours {t_pm / t_read:6.1f}x faster")
        print(f"  pymotion load + fk     {size / 1e6 / t_pm_fk:8.1f} MB/s   ours {t_pm_fk / t_fk:6.1f}x faster "
              f"(same positions to 1e-3 on {files[0].name})")


if __name__ == "__main__":
    main()
