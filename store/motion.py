"""The motion data model shared by every stage (design §2).

Conventions: quaternions are unit ``(w, x, y, z)`` (Hamilton product), joints are ordered so that
parents come before children, joint 0 is the root, lengths are in the file's unit with
``scale_to_m`` giving metres, and the vertical axis is Y unless a config says otherwise.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

#: metres per unit for the length units we know.
UNIT_SCALES: dict[str, float] = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254, "ft": 0.3048}

POSITION_CHANNELS = ("Xposition", "Yposition", "Zposition")
ROTATION_CHANNELS = ("Xrotation", "Yrotation", "Zrotation")


@dataclass(frozen=True, eq=False)
class Skeleton:
    """A joint hierarchy.

    Attributes:
        names: joint names, length J.
        parents: (J,) int, parent index of each joint, -1 for the root; parents precede children.
        offsets: (J, 3) float, each joint's rest offset from its parent, in the file's unit.
        channels: per joint the tuple of channel names in file order, e.g.
            ``("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation")``;
            0, 3 or 6 channels.
        end_sites: ``{joint index: (3,) offset}`` for joints that end in an End Site.
    """

    names: tuple[str, ...]
    parents: np.ndarray
    offsets: np.ndarray
    channels: tuple[tuple[str, ...], ...]
    end_sites: dict[int, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        parents = np.asarray(self.parents, dtype=np.int64)
        offsets = np.asarray(self.offsets, dtype=np.float64).reshape(-1, 3)
        object.__setattr__(self, "parents", parents)
        object.__setattr__(self, "offsets", offsets)
        j = len(self.names)
        if parents.shape != (j,) or offsets.shape != (j, 3) or len(self.channels) != j:
            raise ValueError(f"skeleton arrays disagree on the joint count {j}")
        if j == 0 or parents[0] != -1 or np.any(parents[1:] < 0) or np.any(parents >= np.arange(j)):
            raise ValueError("skeleton parents must list the root first and every parent before its child")

    @property
    def n_joints(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        """Index of the joint called ``name`` (ValueError naming the known joints otherwise)."""
        try:
            return self.names.index(name)
        except ValueError:
            raise ValueError(f"no joint {name!r}; the skeleton has {', '.join(self.names)}") from None

    def rotation_order(self, j: int) -> str:
        """The Euler order of joint ``j``'s rotation channels, e.g. ``"ZXY"`` ('' if none)."""
        return "".join(c[0] for c in self.channels[j] if c in ROTATION_CHANNELS)

    def has_position(self, j: int) -> bool:
        return any(c in POSITION_CHANNELS for c in self.channels[j])

    def signature(self) -> str:
        """A short hash of the topology (names and parents), equal for clips that can be compared."""
        text = ";".join(f"{n}<{p}" for n, p in zip(self.names, self.parents.tolist(), strict=True))
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    def children(self, j: int) -> list[int]:
        return [int(c) for c in np.flatnonzero(self.parents == j)]


@dataclass(frozen=True, eq=False)
class Motion:
    """A clip: a skeleton animated over F frames.

    Attributes:
        skeleton: the joint hierarchy.
        fps: frames per second.
        root_positions: (F, 3) root translation in the file's unit.
        rotations: (F, J, 4) local joint rotations, unit quaternions (w, x, y, z).
        name: clip name (file stem by default).
        source: path of the file it came from, if any.
        content_hash: SHA-256 of the source file's bytes ('' when not from a file).
        unit: the length unit ('m', 'cm', 'in', ...) or None when the file does not declare one.
        scale_to_m: metres per unit (None when the unit is unknown).
        translations: ``{joint index: (F, 3)}`` per-frame translations of non-root joints that
            carry position channels (they replace the joint's offset in forward kinematics).
    """

    skeleton: Skeleton
    fps: float
    root_positions: np.ndarray
    rotations: np.ndarray
    name: str = ""
    source: str | None = None
    content_hash: str = ""
    unit: str | None = None
    scale_to_m: float | None = None
    translations: dict[int, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        root = np.asarray(self.root_positions, dtype=np.float64)
        rot = np.asarray(self.rotations, dtype=np.float64)
        object.__setattr__(self, "root_positions", root)
        object.__setattr__(self, "rotations", rot)
        f = rot.shape[0]
        if rot.shape != (f, self.skeleton.n_joints, 4) or root.shape != (f, 3):
            raise ValueError(
                f"motion arrays disagree: rotations {rot.shape}, root {root.shape}, "
                f"{self.skeleton.n_joints} joints"
            )
        if not self.fps > 0:
            raise ValueError(f"fps must be positive, got {self.fps}")
        if self.unit is not None and self.scale_to_m is None and self.unit in UNIT_SCALES:
            object.__setattr__(self, "scale_to_m", UNIT_SCALES[self.unit])

    @property
    def n_frames(self) -> int:
        return self.rotations.shape[0]

    @property
    def duration(self) -> float:
        """Seconds from the first to the last frame."""
        return (self.n_frames - 1) / self.fps

    def local_translations(self) -> np.ndarray:
        """(F, J, 3) per-frame local translation of every joint (offset, or channel values)."""
        t = np.broadcast_to(self.skeleton.offsets, (self.n_frames, self.skeleton.n_joints, 3)).copy()
        t[:, 0] = self.root_positions
        for j, tr in self.translations.items():
            t[:, j] = tr
        return t

    def slice(self, start: int, stop: int) -> Motion:
        """Frames ``start:stop`` as a new clip."""
        return replace(
            self,
            root_positions=self.root_positions[start:stop],
            rotations=self.rotations[start:stop],
            translations={j: t[start:stop] for j, t in self.translations.items()},
        )

    def metres(self) -> float:
        """Metres per unit; raises a clear error when the unit is unknown."""
        if self.scale_to_m is None:
            raise ValueError(
                f"{self.source or self.name}: the length unit is not declared by the file; "
                "set `length_unit` (m, cm, mm, in, ft) or `scale_to_m` in the config"
            )
        return self.scale_to_m


def file_hash(path: str | Path) -> str:
    """SHA-256 hex digest of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()
