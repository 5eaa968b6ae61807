"""Where the real motion capture lives (never part of the repo).

``MOTIONWEB_MOCAP`` names the folder. Without it the default is ``../shared/data/mocap`` seen from
the working directory (the checkout's root when tests and benchmarks run); from a deeper folder
(a git worktree, say) the nearest ancestor holding ``shared/data/mocap`` is used. Nothing depends on
where the package is installed, so an editable and an installed package read the same data.
"""

from __future__ import annotations

import os
from pathlib import Path

ENV_VAR = "MOTIONWEB_MOCAP"
DEFAULT = Path("shared") / "data" / "mocap"


def mocap_root() -> Path:
    """The folder of real motion capture: $MOTIONWEB_MOCAP, else ../shared/data/mocap from the cwd
    (or from its nearest ancestor that has one). It may not exist: callers skip or say so."""
    env = os.environ.get(ENV_VAR)
    if env:
        return Path(env)
    cwd = Path.cwd().resolve()
    for base in cwd.parents:
        if (base / DEFAULT).is_dir():
            return base / DEFAULT
    return cwd.parent / DEFAULT
