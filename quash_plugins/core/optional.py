"""Importing optional dependencies with a message that names the extra to install."""

from __future__ import annotations

import importlib
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
