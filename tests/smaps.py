"""Resident memory of a process's file mappings, read from Linux's /proc/self/smaps (tests of the
mapped graph files, store/filecache.py)."""

from __future__ import annotations

import os
from pathlib import Path

#: whether this system reports its mappings (Linux)
HAVE_SMAPS = os.path.exists("/proc/self/smaps")


def mapping_rss_kb(path: str | os.PathLike[str]) -> int:
    """Resident kB of this process's mappings of the file ``path``."""
    total, inside = 0, False
    for line in Path("/proc/self/smaps").read_text().split("\n"):
        head = line.split()
        if head and "-" in head[0] and len(head) >= 5:  # a mapping's first line
            inside = line.endswith(str(path))
        elif inside and line.startswith("Rss:"):
            total += int(head[1])
    return total
