"""Importing optional dependencies with a message that names the extra to install."""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Mapping
from typing import Any

from .errors import QuashError


def require(module: str, extra: str, purpose: str, error: type[QuashError] = QuashError) -> Any:
    """Import ``module``, or raise ``error`` saying what needs it and how to install it.

    Examples
    --------
    >>> require("json", "none", "Reading JSON").__name__
    'json'
    """
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise error(
            f"{purpose} needs the Python package {module.split('.')[0]!r} ({exc}). Install "
            f'it with: pip install "quash-plugins[{extra}]"'
        ) from None


def lazy_exports(
    package: str, exports: Mapping[str, str]
) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """A package's module-level ``__getattr__`` and ``__dir__`` for names imported on
    first use, so that importing the package imports none of the modules behind them.

    ``exports`` maps each name to the module that defines it, relative to ``package``
    (``".pipeline"``); a name that is that module's own last part (``"registry":
    ".core.registry"``) is the module itself. A value is kept in the package once loaded.

    Examples
    --------
    >>> get, names = lazy_exports("json", {"JSONDecoder": ".decoder"})
    >>> get("JSONDecoder").__name__, "JSONDecoder" in names()
    ('JSONDecoder', True)
    """

    def __getattr__(name: str) -> Any:
        module = exports.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        found = importlib.import_module(module, package)
        value = found if found.__name__.endswith(f".{name}") else getattr(found, name)
        setattr(sys.modules[package], name, value)
        return value

    def __dir__() -> list[str]:
        return sorted(set(vars(sys.modules[package])) | set(exports))

    return __getattr__, __dir__
