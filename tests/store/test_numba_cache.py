"""The kernels' on-disk cache is stamped by every kernel source of the package (store/numba_cache.py)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from motionweb.store import numba_cache
from motionweb.store.numba_cache import source_digest

ROOT = Path(__file__).resolve().parents[2]

CALLER = """
from callee import value
from numba import njit


@njit(cache=True)
def total():
    return value() + 10
"""

RUN = """
import sys
from pathlib import Path

sys.path.insert(0, {pkg!r})
from motionweb.store import numba_cache

if {stamped!r}:
    numba_cache.ROOTS[:] = [Path({pkg!r})]
    numba_cache.install()
import caller

print(caller.total())
"""


def test_every_kernel_is_declared_through_the_stamped_njit() -> None:
    """A kernel declared with numba's own njit would be cached under its file's stamp alone."""
    offenders = []
    for folder in ("store", "tasks"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            if path.name == "numba_cache.py":
                continue
            text = path.read_text()
            if re.search(r"^from numba import .*\b(njit|jit)\b|\bnumba\.(njit|jit)\(", text, re.M):
                offenders.append(str(path.relative_to(ROOT)))
    assert offenders == []


def test_the_digest_follows_every_source_file(tmp_path: Path) -> None:
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "sub").mkdir()
    (tmp_path / "a" / "x.py").write_text("x = 1\n")
    (tmp_path / "a" / "sub" / "y.py").write_text("y = 1\n")
    roots = (tmp_path / "a",)
    first = source_digest.__wrapped__(roots)
    assert source_digest.__wrapped__(roots) == first
    (tmp_path / "a" / "sub" / "y.py").write_text("y = 2\n")
    assert source_digest.__wrapped__(roots) != first
    (tmp_path / "a" / "sub" / "y.py").write_text("y = 1\n")
    assert source_digest.__wrapped__(roots) == first
    (tmp_path / "a" / "z.py").write_text("")
    assert source_digest.__wrapped__(roots) != first


def test_the_package_kernels_use_the_stamped_locator() -> None:
    from motionweb.tasks.matchweb.band import band_dp

    assert isinstance(band_dp._cache._impl.locator, numba_cache.PackageStampLocator)


def _total(pkg: Path, cache: Path, stamped: bool) -> int:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}
    r = subprocess.run([sys.executable, "-c", RUN.format(pkg=str(pkg), stamped=stamped)], env=env,
                       capture_output=True, text=True, timeout=300, check=False)
    assert r.returncode == 0, r.stderr
    return int(r.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("stamped", [True, False], ids=["stamped", "numba-alone"])
def test_an_edited_callee_is_compiled_into_its_cached_caller(tmp_path: Path, stamped: bool) -> None:
    """Two processes: the first caches ``total`` (which compiles ``value`` into itself); the callee's
    file is edited; the second must run the new callee. numba alone loads the stale caller (the
    control case: if a numba release fixes that, it fails and this module can go)."""
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    (pkg / "caller.py").write_text(CALLER)
    callee = pkg / "callee.py"
    callee.write_text(textwrap.dedent("""
        from numba import njit


        @njit(cache=True)
        def value():
            return 1
    """))
    assert _total(pkg, tmp_path / "cache", stamped) == 11
    callee.write_text(callee.read_text().replace("return 1", "return 2"))
    assert _total(pkg, tmp_path / "cache", stamped) == (12 if stamped else 11)
