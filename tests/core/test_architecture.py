"""The import rules of docs/architecture.md, checked on the source tree.

Every import statement of the package (module level and inside functions; docstring
examples are not imports) is resolved to a module of ``quash_plugins`` and checked:

- each folder imports only the folders its rule allows (``core`` nothing outside itself,
  a plugin package only ``core``, the engine only ``core``...);
- no module imports a private module (``_name``) of another package;
- the benchmarks and the example plugins use public modules only.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PKG = ROOT / "quash_plugins"

PLUGINS = {"encoders", "heuristics", "classifiers", "adapters"}
#: folder -> folders of quash_plugins it may import (itself always allowed).
ALLOWED: dict[str, set[str]] = {
    "core": set(),
    "data": set(),
    "encoders": {"core"},
    "heuristics": {"core"},
    "classifiers": {"core"},
    "adapters": {"core"},
    "engine": {"core"},
    "viewer": {"core"},
    "testing": {"core"},
    "evaluation": {"core", "engine"},
    "integrations": {"core", "engine", "adapters"},
    "demo": {"core", "engine", "evaluation", "viewer", "adapters"},
    "cli": {
        "core",
        "engine",
        "evaluation",
        "viewer",
        "demo",
        "adapters",
        "encoders",
        "heuristics",
        "classifiers",
        "integrations",
    },
}


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _imports(path: Path) -> list[tuple[int, str]]:
    """Absolute names of the ``quash_plugins`` modules (or names) imported by ``path``."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    mod = _module_name(path)
    is_pkg = path.name == "__init__.py"
    package = mod.split(".") if is_pkg else mod.split(".")[:-1]
    out: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            out += [(node.lineno, f"{target}.{a.name}") for a in node.names]
    return [(n, name) for n, name in out if name.split(".")[0] == "quash_plugins"]


def _folder(name: str) -> str | None:
    parts = name.split(".")
    return parts[1] if len(parts) > 2 or (len(parts) == 2 and (PKG / parts[1]).is_dir()) else None


def _private_module_of_other_package(importer: str, name: str) -> bool:
    """``name`` goes through a ``_private`` module of a package that is not the importer's."""
    parts = name.split(".")
    for i in range(1, len(parts)):
        if parts[i].startswith("_") and not parts[i].startswith("__"):
            owner = ".".join(parts[:i])
            target = PKG.parent.joinpath(*parts[: i + 1])
            if not (target.with_suffix(".py").exists() or target.is_dir()):
                return False  # a private *name*, not a private module
            return not importer.startswith(owner + ".") and importer != owner
    return False


SOURCES = sorted(p for p in PKG.rglob("*.py") if "__pycache__" not in p.parts)


def test_every_folder_of_the_package_has_a_rule():
    folders = {p.name for p in PKG.iterdir() if p.is_dir() and (p / "__init__.py").exists()}
    assert folders == set(ALLOWED), "add the new folder to ALLOWED and to the docs"


@pytest.mark.parametrize("path", SOURCES, ids=lambda p: str(p.relative_to(PKG)))
def test_folder_imports_follow_the_rules(path):
    rel = path.relative_to(PKG).parts
    if len(rel) == 1:
        return  # the top-level __init__ re-exports the public API
    folder = rel[0]
    allowed = ALLOWED[folder] | {folder}
    bad = [
        f"line {n}: {name}"
        for n, name in _imports(path)
        if (f := _folder(name)) is not None and f not in allowed
    ]
    assert not bad, f"{folder}/ may import only {sorted(allowed)}; found {bad}"


@pytest.mark.parametrize("path", SOURCES, ids=lambda p: str(p.relative_to(PKG)))
def test_no_private_module_of_another_package(path):
    importer = _module_name(path)
    bad = [
        f"line {n}: {name}"
        for n, name in _imports(path)
        if _private_module_of_other_package(importer, name)
    ]
    assert not bad, f"{importer} imports private modules of other packages: {bad}"


OUTSIDE = sorted(
    p
    for d in ("benchmarks", "examples")
    for p in (ROOT / d).rglob("*.py")
    if "__pycache__" not in p.parts
)


@pytest.mark.parametrize("path", OUTSIDE, ids=lambda p: str(p.relative_to(ROOT)))
def test_benchmarks_and_examples_use_public_modules(path):
    bad = [
        f"line {n}: {name}"
        for n, name in _imports(path)
        if _private_module_of_other_package("__user__", name)
    ]
    assert not bad, f"{path.relative_to(ROOT)} imports private modules: {bad}"


def test_the_rules_can_fail(tmp_path):
    """The checker itself: a core module importing a plugin package is caught."""
    assert _folder("quash_plugins.classifiers._svm.RbfSvmClassifier") == "classifiers"
    assert _folder("quash_plugins.registry") is None or not (PKG / "registry").is_dir()
    assert _private_module_of_other_package(
        "quash_plugins.engine.pipeline", "quash_plugins.heuristics._mined.add_map_negatives"
    )
    assert not _private_module_of_other_package(
        "quash_plugins.heuristics._taxonomy", "quash_plugins.heuristics._data.read_mapping"
    )
    assert not _private_module_of_other_package(
        "quash_plugins.engine.pipeline", "quash_plugins.core.types._dedupe"
    )
