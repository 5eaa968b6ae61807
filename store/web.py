"""The match web data class (KG04 §3.2, Fig. 7): what the index computes and the store keeps.

A web is stored and searched, so it lives in the store layer; the stages that build it
(:mod:`motionweb.tasks.matchweb`) and search it (:mod:`motionweb.tasks.search`) import it from here.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from motionweb.store.cache import array_bytes


def empty_cells() -> np.ndarray:
    return np.zeros((0, 2), dtype=np.int32)


@dataclass
class MatchWeb:
    """A match web between clips A (rows) and B (columns) at ``rate`` Hz (KG04 §3.2, Fig. 7).

    Paths (the refined minima chains) are ragged: path ``p`` is
    ``paths_cells[paths_offsets[p]:paths_offsets[p + 1]]`` (monotone cells, row = frame of A,
    column = frame of B) with the grid values there in ``paths_values``.

    Bridge ``b`` is a junction ``bridges[b] = (from_path, from_index, to_path, to_index)``: it
    leaves path ``from_path`` at its cell number ``from_index`` (index within that path) and joins
    path ``to_path`` at its cell number ``to_index``. Its own cells are
    ``bridges_cells[bridges_offsets[b]:bridges_offsets[b + 1]]``, monotone, the first equal to the
    from-cell and the last to the to-cell (both included).

    ``grid`` is the full distance grid at ``rate`` when asked for (``keep_grids``), else None.
    """

    rate: float
    shape: tuple[int, int]
    paths_cells: np.ndarray = field(default_factory=empty_cells)
    paths_values: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    paths_offsets: np.ndarray = field(default_factory=lambda: np.zeros(1, np.int64))
    bridges: np.ndarray = field(default_factory=lambda: np.zeros((0, 4), np.int64))
    bridges_cells: np.ndarray = field(default_factory=empty_cells)
    bridges_values: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    bridges_offsets: np.ndarray = field(default_factory=lambda: np.zeros(1, np.int64))
    self_pair: bool = False
    grid: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.rate = float(self.rate)
        self.shape = (int(self.shape[0]), int(self.shape[1]))
        self.paths_cells = np.asarray(self.paths_cells, dtype=np.int32).reshape(-1, 2)
        self.paths_values = np.asarray(self.paths_values, dtype=np.float32).reshape(-1)
        self.paths_offsets = np.asarray(self.paths_offsets, dtype=np.int64).reshape(-1)
        self.bridges = np.asarray(self.bridges, dtype=np.int64).reshape(-1, 4)
        self.bridges_cells = np.asarray(self.bridges_cells, dtype=np.int32).reshape(-1, 2)
        self.bridges_values = np.asarray(self.bridges_values, dtype=np.float32).reshape(-1)
        self.bridges_offsets = np.asarray(self.bridges_offsets, dtype=np.int64).reshape(-1)
        if self.paths_offsets[-1] != len(self.paths_cells) or len(self.paths_values) != len(self.paths_cells):
            raise ValueError("path offsets, cells and values disagree")
        if self.bridges_offsets[-1] != len(self.bridges_cells) or len(self.bridges_offsets) != len(self.bridges) + 1:
            raise ValueError("bridge offsets, cells and junctions disagree")

    @property
    def n_paths(self) -> int:
        return len(self.paths_offsets) - 1

    @property
    def n_bridges(self) -> int:
        return len(self.bridges)

    @property
    def nbytes(self) -> int:
        """Bytes of its arrays (the grid included when kept): what a cache of webs counts."""
        return array_bytes(self.paths_cells, self.paths_values, self.paths_offsets, self.bridges,
                           self.bridges_cells, self.bridges_values, self.bridges_offsets, self.grid)

    def path(self, p: int) -> tuple[np.ndarray, np.ndarray]:
        """(cells (n, 2), values (n,)) of path ``p``."""
        a, b = self.paths_offsets[p], self.paths_offsets[p + 1]
        return self.paths_cells[a:b], self.paths_values[a:b]

    def bridge(self, b: int) -> tuple[np.ndarray, np.ndarray]:
        """(cells (n, 2), values (n,)) of bridge ``b``."""
        s, e = self.bridges_offsets[b], self.bridges_offsets[b + 1]
        return self.bridges_cells[s:e], self.bridges_values[s:e]

    def paths(self) -> list[np.ndarray]:
        return [self.path(p)[0] for p in range(self.n_paths)]

    def to_arrays(self) -> dict[str, np.ndarray]:
        """Flat arrays only (scalars as shape-(1,) arrays), e.g. for a Zarr group."""
        d = {
            "rate": np.array([self.rate], dtype=np.float64),
            "shape": np.array(self.shape, dtype=np.int64),
            "self_pair": np.array([self.self_pair], dtype=np.bool_),
            "paths_cells": self.paths_cells,
            "paths_values": self.paths_values,
            "paths_offsets": self.paths_offsets,
            "bridges": self.bridges,
            "bridges_cells": self.bridges_cells,
            "bridges_values": self.bridges_values,
            "bridges_offsets": self.bridges_offsets,
        }
        if self.grid is not None:
            d["grid"] = self.grid
        return d

    @classmethod
    def from_arrays(cls, d: dict[str, np.ndarray]) -> MatchWeb:
        """Inverse of :meth:`to_arrays` (accepts anything indexable like numpy arrays)."""
        arr = {k: np.asarray(v[...]) for k, v in d.items()}
        return cls(
            rate=float(arr["rate"].reshape(-1)[0]),
            shape=tuple(int(x) for x in arr["shape"].reshape(-1)),
            paths_cells=arr["paths_cells"],
            paths_values=arr["paths_values"],
            paths_offsets=arr["paths_offsets"],
            bridges=arr["bridges"],
            bridges_cells=arr["bridges_cells"],
            bridges_values=arr["bridges_values"],
            bridges_offsets=arr["bridges_offsets"],
            self_pair=bool(arr["self_pair"].reshape(-1)[0]) if "self_pair" in arr else False,
            grid=arr.get("grid"),
        )


def transpose(web: MatchWeb) -> MatchWeb:
    """The web with rows and columns swapped: cells (i, j) -> (j, i). Paths and bridges stay
    monotone and keep their order, so junction indices are unchanged. O(cells)."""
    return MatchWeb(
        rate=web.rate, shape=(web.shape[1], web.shape[0]),
        paths_cells=web.paths_cells[:, ::-1].copy(), paths_values=web.paths_values, paths_offsets=web.paths_offsets,
        bridges=web.bridges, bridges_cells=web.bridges_cells[:, ::-1].copy(), bridges_values=web.bridges_values,
        bridges_offsets=web.bridges_offsets, self_pair=web.self_pair,
        grid=None if web.grid is None else np.ascontiguousarray(web.grid.T),
    )
