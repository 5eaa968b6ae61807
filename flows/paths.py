"""Path rules shared by the config loader and the light CLI client (standard library only)."""

from __future__ import annotations

from pathlib import Path


def resolve_path(path: str | None, base: Path) -> str | None:
    """A config's relative local path made absolute against ``base`` (the config's folder);
    fsspec URLs and absolute paths are left alone."""
    if path is None or "://" in path or Path(path).is_absolute():
        return path
    return str((base / path).resolve())
