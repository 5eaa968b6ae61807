"""numba's on-disk cache of the compiled kernels, keyed on every kernel source of the package.

numba keeps a kernel's machine code (``cache=True``) under a stamp of the kernel's own source
file only. A kernel compiles the kernels it calls into its own code, so after an edit of a callee
in another file (``tasks/matchweb/band.py``'s ``band_dp``, called by ``refine._solve``) the
caller's cached code, callee included, would still load and run the old callee: an editable
install updated by ``git pull`` runs stale code without a word. :func:`install` puts a locator in
front of numba's own (``numba.core.caching.CacheImpl._locator_classes``) for the kernels in the
package's folders: the same cache folder and file names as the locator numba would have chosen,
with the stamp extended by a digest of every ``.py`` file under those folders
(:func:`source_digest`), so an edit of any of them makes every cached kernel of the package
compile again, and nothing else changes. The kernels are declared with :func:`njit`, which
installs it first (the CLI's start, which loads no kernel, does not import numba).
``tests/store/test_numba_cache.py`` edits a callee between two processes and checks the caller
runs the new code.

Cost: one read and SHA-256 of the package's kernel sources per process (~150 files, a few ms),
on the first kernel it loads or compiles; a release install changes nothing (its files are new
anyway); a developer's edit of any kernel source recompiles the package's kernels once (~20 s).
"""

from __future__ import annotations

import functools
import hashlib
from pathlib import Path
from typing import Any

#: folders whose kernels are stamped with :func:`source_digest` of them (the package's store and tasks)
ROOTS: list[Path] = [Path(__file__).resolve().parent, Path(__file__).resolve().parent.parent / "tasks"]


@functools.cache
def source_digest(roots: tuple[Path, ...]) -> str:
    """SHA-256 over the relative paths and bytes of every ``.py`` file under ``roots``, in path order."""
    h = hashlib.sha256()
    for root in roots:
        for path in sorted(root.rglob("*.py")):
            h.update(str(path.relative_to(root.parent)).encode())
            h.update(b"\0")
            h.update(path.read_bytes())
            h.update(b"\0")
    return h.hexdigest()


class PackageStampLocator:
    """numba's locator for a kernel under :data:`ROOTS`, with the stamp extended by
    :func:`source_digest` of them (the module docstring says why)."""

    def __init__(self, inner: Any, roots: tuple[Path, ...]) -> None:
        self._inner = inner
        self._roots = roots
        self._py_file = getattr(inner, "_py_file", "")  # numba's warnings name it

    def ensure_cache_path(self) -> None:
        self._inner.ensure_cache_path()

    def get_cache_path(self) -> str:
        return self._inner.get_cache_path()

    def get_source_stamp(self) -> Any:
        return (self._inner.get_source_stamp(), source_digest(self._roots))

    def get_disambiguator(self) -> str:
        return self._inner.get_disambiguator()

    @classmethod
    def from_function(cls, py_func: Any, py_file: str) -> PackageStampLocator | None:
        roots = tuple(ROOTS)
        try:
            path = Path(py_file).resolve()
        except OSError:
            return None
        if not any(path.is_relative_to(root) for root in roots):
            return None
        from numba.core.caching import CacheImpl

        for other in CacheImpl._locator_classes:
            if other is cls:
                continue
            inner = other.from_function(py_func, py_file)
            if inner is not None:
                return cls(inner, roots)
        return None


def njit(*args: Any, **kwargs: Any) -> Any:
    """``numba.njit`` after :func:`install`: every kernel of the package is declared with it, so
    its cache is stamped by the package's sources (``tests/store/test_numba_cache.py`` checks
    that no module declares one with numba's own)."""
    install()
    import numba

    return numba.njit(*args, **kwargs)


def install() -> None:
    """Put :class:`PackageStampLocator` first among numba's cache locators (once per process);
    numba's own ``NUMBA_CACHE_LOCATOR_CLASSES``, when set, still overrides the list."""
    from numba.core.caching import CacheImpl

    if PackageStampLocator not in CacheImpl._locator_classes:
        CacheImpl._locator_classes.insert(0, PackageStampLocator)
