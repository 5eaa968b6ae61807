"""Where the real motion-capture data lives (not part of the repo).

``MOTIONWEB_MOCAP`` overrides the default ``../shared/data/mocap`` (relative to the repo root).
"""

from __future__ import annotations

import os
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parent.parent
ENV_VAR = "MOTIONWEB_MOCAP"


def mocap_root() -> Path:
    """The folder of real motion capture: $MOTIONWEB_MOCAP or ../shared/data/mocap."""
    env = os.environ.get(ENV_VAR)
    return Path(env) if env else (REPO_ROOT.parent / "shared" / "data" / "mocap").resolve()
