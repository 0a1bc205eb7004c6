"""Install a plugin distribution for a test, offline, into a private folder."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path


def pip_install(project: Path, target: Path) -> None:
    """``pip install --target target project`` without the network or build isolation."""
    subprocess.run(
        [sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-build-isolation"]
        + ["--no-index", "--target", str(target), str(project)],
        check=True,
        capture_output=True,
        text=True,
    )
