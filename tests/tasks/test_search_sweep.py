"""The crash sweep of ``bench/sweep.py`` on a subset of the shared CMU set (issue 22).

Every window (0.5, 1 and 2 s, every 0.25 s and the last possible start) of a few trials of
different subjects and categories, queried against an unsplit index of them, with the default ε
rule at 1, 3 and 20 tiers: no exception. CI runs it a second time with NUMBA_BOUNDSCHECK=1 (the
``compiled`` pass of .ci/run), where a write out of bounds is an IndexError.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
#: jumps and a walk of subject 16, the playground jump of 01 (the clip of issue 22's crash) and a
#: kick of 135 (a crash of the first sweep): several skeletons, categories and lengths
SUBSET = {"asf_amc/16/16_01.amc": "jump", "asf_amc/16/16_15.amc": "walk", "asf_amc/16/16_35.amc": "run",
          "asf_amc/01/01_01.amc": "jump", "asf_amc/135/135_04.amc": "kick"}


def _bench(name: str):
    spec = importlib.util.spec_from_file_location(f"_bench_{name}", ROOT / "bench" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # dataclasses look their module up
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.slow
def test_every_window_of_real_trials_is_searched_without_an_exception(cmu_dir, tmp_path) -> None:
    from motionweb.tasks.features import FeatureParams
    from motionweb.tasks.matchweb.params import MatchWebParams

    sweep, retrieval = _bench("sweep"), _bench("retrieval")
    files = {p: c for p, c in SUBSET.items() if (cmu_dir / p).is_file()}
    if len(files) < len(SUBSET):
        pytest.skip(f"CMU trials missing under {cmu_dir}: {sorted(set(SUBSET) - set(files))}")
    lib = retrieval.load_library(cmu_dir, tmp_path / "webs", FeatureParams(), MatchWebParams(), files)
    assert sorted(lib.clips) == sorted(SUBSET) and all(lib.webs[c] for c in lib.clips)
    res = sweep.sweep(lib.webs, [1, 3, 20], [0.5, 1.0, 2.0], 0.25, MatchWebParams())
    # every clip, every length, a start every 0.25 s (8 frames at 30 Hz) and the last one
    per_clip = {c: len(list(sweep.windows(n, 30.0, [0.5, 1.0, 2.0], 0.25))) for c, n in lib.frames.items()}
    assert res.queries == sum(per_clip.values()) and res.queries >= sum(lib.frames.values()) * 3 // 9
    assert res.failures == [], "\n".join(res.failures[:10])
    assert res.searches == 3 * res.queries and res.empty < res.queries
