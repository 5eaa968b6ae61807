"""bench/scale.py's pieces that need no index run: the power-law fit, the corpus check and the
expected pairs and cells (the benchmark itself is not run by the tests)."""

from __future__ import annotations

import itertools
import math
from pathlib import Path
from types import SimpleNamespace

import pytest
from motionweb.flows.config import Config
from motionweb.store.catalog import scan_corpus
from motionweb.store.demo.takes import write_take_corpus

from bench.corpus import CorpusError
from bench.scale import check_scale_corpus, expected_pairs, fit_power, fit_work, predict


def test_fit_power_recovers_exponent_and_refuses_few_sizes() -> None:
    x = [20_000, 40_000, 80_000, 150_000]
    y = [3.0 * v ** 1.7 for v in x]
    p, c = fit_power(x, y)
    assert p == pytest.approx(1.7) and c == pytest.approx(3.0)
    assert predict((p, c), 1e6) == pytest.approx(3.0 * 1e6 ** 1.7)
    with pytest.raises(ValueError, match="at least 4"):
        fit_power(x[:3], y[:3])
    with pytest.raises(ValueError, match="at least 4"):
        fit_power([1, 1, 2, 3], [1, 1, 2, 3])  # distinct sizes only
    with pytest.raises(ValueError, match="positive"):
        fit_power(x, [0.0, *y[1:]])


def test_fit_work_recovers_fixed_cost_and_cost_per_cell() -> None:
    cells = [4e7, 1e8, 4e8, 1.7e9]
    a, b = fit_work(cells, [6.0 + 7e-8 * c for c in cells])
    assert a == pytest.approx(6.0) and b == pytest.approx(7e-8)
    a, b = fit_work([1.0, 2.0, 3.0], [0.0, 3.0, 5.0])  # a negative intercept: through the origin
    assert a == 0.0 and b == pytest.approx(21 / 14)  # Σxy / Σx²
    with pytest.raises(ValueError, match="at least 2"):
        fit_work([1.0, 1.0], [2.0, 3.0])
    with pytest.raises(ValueError, match="never negative"):
        fit_work([1.0, 2.0], [-1.0, 3.0])


def test_expected_pairs_counts_per_category_and_skeleton() -> None:
    def e(cat: str, sk: str, sha: str, d: float) -> SimpleNamespace:
        return SimpleNamespace(category=cat, skeleton=sk, sha256=sha, duration=d)

    entries = [e("a", "s", "1", 1.0), e("a", "s", "2", 2.0), e("a", "t", "3", 1.0), e("b", "s", "4", 0.5),
               e("b", "s", "4", 0.5)]  # an identical file: one web
    pairs, cells = expected_pairs(entries, 60.0)
    assert pairs == 3 + 1 + 1
    f = {k: math.floor(d * 60 + 1e-9) + 1 for k, d in (("1", 1.0), ("2", 2.0), ("3", 1.0), ("4", 0.5))}
    brute = sum(f[a] * f[b] for g in (["1", "2"], ["3"], ["4"]) for a, b in itertools.combinations_with_replacement(g, 2))
    assert cells == brute


def test_corpus_check(tmp_path: Path) -> None:
    out = tmp_path / "c"
    paths = write_take_corpus(out, 1000, seed=1)
    cat = scan_corpus(out, Config.model_validate({"corpus": {"length_unit": "m"}}).corpus)
    expected = {p.relative_to(out).as_posix(): p.parent.name for p in paths}
    frames = check_scale_corpus(out, cat, expected, 1000)
    assert frames >= 1000
    with pytest.raises(CorpusError, match="fewer than"):
        check_scale_corpus(out, cat, expected, frames + 1)
    with pytest.raises(CorpusError, match="another category"):
        check_scale_corpus(out, cat, {k: "elsewhere" for k in expected}, 1000)
    with pytest.raises(CorpusError, match="were written"):
        check_scale_corpus(out, cat, {**expected, "walk/missing.bvh": "walk"}, 1000)
