"""Every name a package exports (``__all__``, lazy exports included) can be imported."""

from __future__ import annotations

import importlib
import pkgutil

import pytest

import quash_plugins

PACKAGES = ["quash_plugins"] + sorted(
    f"quash_plugins.{m.name}" for m in pkgutil.iter_modules(quash_plugins.__path__) if m.ispkg
)


@pytest.mark.parametrize("package", PACKAGES)
def test_every_exported_name_resolves(package):
    mod = importlib.import_module(package)
    broken = []
    for name in getattr(mod, "__all__", []):
        try:
            getattr(mod, name)
        except (ImportError, AttributeError) as exc:
            broken.append(f"{name}: {type(exc).__name__}: {exc}")
    assert not broken, f"{package}.__all__ names what it cannot import: {broken}"
