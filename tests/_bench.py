"""Load a script of ``benchmarks/`` as a module (they are scripts, not a package), and
the small scene the ``quash bench`` tests run on."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


def load_bench(name: str) -> ModuleType:
    """``benchmarks/NAME.py`` as a module; ``benchmarks/`` is on ``sys.path`` while it
    loads, for the scripts that import ``bench_quality``."""
    sys.path.insert(0, str(BENCHMARKS))
    try:
        spec = importlib.util.spec_from_file_location(name, BENCHMARKS / f"{name}.py")
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
    finally:
        sys.path.remove(str(BENCHMARKS))
    return mod


def hashing_scene(tmp_path_factory, encoder: str):
    """A fixture's body: a one-room ``quash make-scene`` folder (``scene.npz`` and its
    side files) embedded by the hashing encoder registered as ``encoder`` meanwhile."""
    from quash_plugins.cli.main import main
    from quash_plugins.core import registry
    from quash_plugins.testing import HashingEncoder

    registry.register("encoders", encoder, HashingEncoder, replace=True)
    d = tmp_path_factory.mktemp("bench")
    args = ["make-scene", str(d / "scene.npz"), "--encoder", encoder, "--no-cache"]
    assert main([*args, "--rooms", "1", "--voxel-size", "0.25"]) == 0
    yield d
    registry.unregister("encoders", encoder)
