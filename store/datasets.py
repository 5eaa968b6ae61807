"""Where the real motion capture lives (never part of the repo).

``MOTIONWEB_MOCAP`` names the folder; without it the default is ``../shared/data/mocap`` relative to
the working directory (the checkout's root when tests and benchmarks run), so the same path works
for an editable and an installed package.
"""

from __future__ import annotations

import os
from pathlib import Path

ENV_VAR = "MOTIONWEB_MOCAP"
DEFAULT = Path("..") / "shared" / "data" / "mocap"


def mocap_root() -> Path:
    """The folder of real motion capture: $MOTIONWEB_MOCAP or ../shared/data/mocap (from the cwd)."""
    env = os.environ.get(ENV_VAR)
    return Path(env) if env else (Path.cwd() / DEFAULT).resolve()
