"""Every clip under the real-data folder loads, whatever its format (skips where absent)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from motionweb.store.bvh import format_bvh, parse_bvh
from motionweb.store.formats import is_clip, read_motion
from motionweb.store.kinematics import forward_kinematics


def test_every_real_clip_loads_and_round_trips_through_bvh(mocap_dir: Path) -> None:
    files = sorted(p for p in mocap_dir.rglob("*") if p.is_file() and is_clip(p))
    assert files, f"no clips under {mocap_dir}"
    for path in files:
        m = read_motion(path)
        if m.scale_to_m is None and path.suffix == ".bvh" and "cmu" in path.parts:
            # cgspeed's CMU BVH declares no unit; it keeps the ASF's length unit (1/0.45 in)
            m = read_motion(path, scale_to_m=0.0254 / 0.45)
        assert m.n_frames >= 2 and m.fps > 0, path
        assert m.scale_to_m is not None and 0 < m.scale_to_m <= 1, path
        pos, _ = forward_kinematics(m)
        assert np.isfinite(pos).all(), path
        height = np.ptp(pos[..., 1], axis=1).max() * m.scale_to_m
        assert 0.3 < height < 2.5, (path, height)
        again = parse_bvh(format_bvh(m), unit=m.unit, scale_to_m=m.scale_to_m)
        order = [again.skeleton.index(n) for n in m.skeleton.names]
        np.testing.assert_allclose(forward_kinematics(again)[0][:, order], pos, atol=1e-4, err_msg=str(path))
