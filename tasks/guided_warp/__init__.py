"""Guided time warping (HDP07 = Hsu, da Silva & Popović 2007, §3; design §7).

A time warp of an input motion x_1..x_n is a subsequence y_1..y_m of its frame indices that starts
on the first frame, ends on the last one and never skips more than ``s`` frames (HDP07 §3.1). Its
quality is the sum over output triples of a local score f(y_{p-1}, y_p, y_{p+1}): the mean distance
of the triple's [pose, velocity, acceleration] feature to its k nearest reference features
(HDP07 §3.2, eqs. 1-2). The best subsequence of exactly m frames is a shortest path with m-2 edges
in the DAG whose vertices are frame pairs (i, j), 0 < j - i <= s, and whose edges (i,j)->(j,k) weigh
f(i,j,k) (HDP07 §3.3, eqs. 3-4): O(m n s²) time, O(n s²) scores. Without an output length it is a
plain DAG shortest path, O(n s²).

Every case is reduced to compression (HDP07 §3.1): an expansion upsamples the input by an integer
factor, a backward warp reverses it, several keytimes constrain the path to pass through given
(input frame, output frame) pairs. The result is postprocessed as in HDP07 §3.4: the discrete warp
is moving-averaged, the input is resampled at the warped times (slerp) and each output frame is
averaged over a window equal to the local compression.

Modules: ``features`` (§3.2), ``paths`` (§3.3), ``heuristic`` (§3.3), ``reduction`` (§3.1),
``postprocess`` (§3.4), ``warp`` (the driver and the linear baseline). Index conventions in this package are 0-based: the working input has frames 0..n-1, the output
0..m-1; the path layer p (0..m-2) is the vertex (y[p], y[p+1]).
"""

from motionweb.tasks.guided_warp.features import (
    FeatureSpec,
    Track,
    feature_spec,
    knn_mean_distance,
    local_scores,
    motion_track,
    reference_features,
    torso_positions,
    triple_blocks,
    triple_features,
    triple_index,
)
from motionweb.tasks.guided_warp.heuristic import CoarseSolution, band_windows, coarse_solution, coarse_table
from motionweb.tasks.guided_warp.paths import dag_path, feasible_windows, fixed_length_path, path_cost
from motionweb.tasks.guided_warp.postprocess import apply_warp, smooth_warp
from motionweb.tasks.guided_warp.reduction import Keytime, Reduction, reduce_to_compression
from motionweb.tasks.guided_warp.warp import (
    WarpParams,
    WarpResult,
    check_compatible,
    guided_warp,
    linear_warp,
    playback_speed,
    pose_error,
)

__all__ = [
    "CoarseSolution",
    "FeatureSpec",
    "Keytime",
    "Reduction",
    "Track",
    "WarpParams",
    "WarpResult",
    "apply_warp",
    "band_windows",
    "check_compatible",
    "coarse_solution",
    "coarse_table",
    "dag_path",
    "feasible_windows",
    "feature_spec",
    "fixed_length_path",
    "guided_warp",
    "knn_mean_distance",
    "linear_warp",
    "playback_speed",
    "local_scores",
    "motion_track",
    "path_cost",
    "pose_error",
    "reduce_to_compression",
    "reference_features",
    "smooth_warp",
    "torso_positions",
    "triple_blocks",
    "triple_features",
    "triple_index",
]
