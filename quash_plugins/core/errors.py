"""Exceptions raised for user-facing problems.

Every error a user can cause derives from :class:`QuashError`. The CLI prints the
message (no traceback unless ``--debug``) and exits with status 1; a
:class:`UsageError` exits with status 2.
"""

from __future__ import annotations

import difflib
import importlib.util
import sys
from collections.abc import Iterable


class QuashError(Exception):
    """Base class for errors caused by input, configuration or environment."""


class UsageError(QuashError):
    """The command line or API call itself is malformed (CLI exit status 2)."""


class ConfigError(QuashError):
    """A configuration file or parameter is invalid."""


class PluginError(QuashError):
    """A plugin is unknown, ambiguous, failed to import or breaks its interface."""


class MapFormatError(QuashError):
    """A map file or object does not follow the format its adapter expects."""


class EmptyMapWarning(UserWarning):
    """A map has no items (nothing was fused): every query on it matches nothing."""


class DimensionMismatchError(QuashError):
    """The encoder's embedding dimension differs from the map's."""


class EncoderError(QuashError):
    """An encoder cannot produce an embedding (missing weights, missing table entry...)."""


class HeuristicError(QuashError):
    """A heuristic cannot expand a query (unknown label, unreachable LLM...)."""


def closest(name: str, known: Iterable[str], cutoff: float = 0.5) -> str | None:
    """Return the known name closest to ``name``, or None when nothing is as close as
    ``cutoff`` (difflib's similarity ratio)."""
    matches = close_names(name, known, n=1, cutoff=cutoff)
    return matches[0] if matches else None


def close_names(name: str, known: Iterable[str], n: int = 3, cutoff: float = 0.5) -> list[str]:
    """The (at most ``n``) known names closest to ``name``, closest first; those at least
    ``cutoff`` alike (difflib's similarity ratio).

    >>> close_names("bedd", ["bed", "shed", "desk", "beds"])
    ['bed', 'beds', 'shed']
    """
    return difflib.get_close_matches(name, list(known), n=n, cutoff=cutoff)


def check_options(section: str, options: Iterable[object], known: Iterable[str]) -> None:
    """Refuse an option of a config ``section`` that is not in ``known``, naming the
    options and the closest one (``presence: unknown option 'margn'. ...``)."""
    known = list(known)
    for key in options:
        if key not in known:
            guess = closest(str(key), known)
            hint = f" Did you mean {guess!r}?" if guess else ""
            error = ConfigError(
                f"{section}: unknown option {key!r}. Options: {', '.join(known)}.{hint}"
            )
            error.keys = (section, key)  # where a config file says it (QuashConfig.location)
            raise error


def unknown_name_message(what: str, name: str, known: Iterable[str], *, guess: bool = True) -> str:
    """Format "<what> 'x' is not registered. Known: a, b. Did you mean 'a'?"
    (``guess=False``: without the closest name)."""
    known = sorted(set(known))
    msg = f"{what} {name!r} is not registered. Known: {', '.join(known) or '(none)'}."
    guess = closest(name, known) if guess else None
    if guess is not None:
        msg += f" Did you mean {guess!r}?"
    return msg


def missing_module(exc: BaseException) -> str | None:
    """The top-level module an :class:`ImportError` could not find because it is not
    installed, or None. None too for a module that is installed but lacks what was
    imported from it (``from numpy import typo``, ``import mypackage.no_such_file``):
    installing it is not the fix, and the error's own text names what is missing."""
    name = getattr(exc, "name", None)
    if not isinstance(exc, ModuleNotFoundError) or not name:
        return None
    top = str(name).split(".")[0]
    spec = getattr(sys.modules.get(top), "__spec__", None)
    if sys.modules.get(top) is None:  # None in sys.modules: an import blocked
        try:
            spec = importlib.util.find_spec(top)
        except (ImportError, ValueError):  # a broken finder, a module without a spec
            return top
        if spec is None:
            return top
    # A namespace package (google, azure) is shared by distributions: the one missing
    # is its sub-package's (google.generativeai).
    if spec is not None and spec.origin in (None, "namespace") and "." in str(name):
        sub = ".".join(str(name).split(".")[:2])
        try:
            return sub if importlib.util.find_spec(sub) is None else None
        except (ImportError, ValueError):
            return sub
    return None


def install_hint(module: str, dist: str | None = None) -> str:
    """What to do about a missing Python module (``dist``: the plugin's distribution)."""
    also = f", and list it in the dependencies of {dist!r}" if dist else ""
    return (
        f"needs the Python module {module!r}, which is not installed. Install the package "
        f"that provides it in this environment{also}."
    )
