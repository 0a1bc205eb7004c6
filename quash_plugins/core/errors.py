"""Exceptions raised for user-facing problems.

Every error a user can cause derives from :class:`QuashError`. The CLI prints the
message (no traceback unless ``--debug``) and exits with status 1; a
:class:`UsageError` exits with status 2.
"""

from __future__ import annotations

import difflib
import importlib.util
import sys
from collections.abc import Callable, Iterable
from pathlib import Path


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


def near_paths(
    path: Path,
    suffixes: Iterable[str] | None = None,
    keep: Callable[[Path], bool] | None = None,
    limit: int = 3,
    *,
    cutoff: float = 0.8,
    depth: int = 2,
) -> list[str]:
    """Existing paths whose names are close to a missing ``path``'s, written as ``path``
    was (a relative path stays relative), for "Did you mean ...?".

    Beside ``path``: the names with its stem and another suffix (``quash.yml`` ->
    ``quash.yaml``), else names close to its own. When ``path``'s folder is missing
    too, the same is looked for in the folders with a name close to that folder's
    (``vlmap/vlmaps.h5df`` -> ``vlmap_cam/vlmaps_cam.h5df``). ``suffixes``: only files
    with one of these suffixes; ``keep``: only the paths it accepts; ``cutoff``: how
    alike a close name is (difflib's ratio; folders are matched at 0.6); ``depth``: how
    many missing folders up are looked past. At most the first 1,000 entries of a folder
    are looked at.

    >>> import tempfile, pathlib
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> (d / "quash.yaml").write_text("")
    0
    >>> [pathlib.Path(p).name for p in near_paths(d / "quash.yml")]
    ['quash.yaml']
    """
    path = Path(path)
    suffixes = tuple(suffixes) if suffixes is not None else None
    folder = path.parent
    if _is_dir(folder):
        found = _near_in(folder, path.name, suffixes, keep, cutoff)
    elif depth > 0 and folder.name and folder != folder.parent:
        found = []  # the folder is missing: look in the folders named like it
        for other in near_paths(folder, keep=_is_dir, cutoff=0.6, depth=depth - 1):
            inside = Path(other) / path.name
            if inside.exists() and _kept(inside, suffixes, keep):
                found.append(str(inside))
            else:
                found += _near_in(Path(other), path.name, suffixes, keep, cutoff)
    else:
        return []
    return found[:limit]


def _near_in(
    folder: Path,
    name: str,
    suffixes: tuple[str, ...] | None,
    keep: Callable[[Path], bool] | None,
    cutoff: float,
) -> list[str]:
    """Entries of ``folder`` with ``name``'s stem, else a name close to it (closest first)."""
    import itertools
    import os

    try:
        with os.scandir(folder) as it:
            names = sorted(e.name for e in itertools.islice(it, 1000) if not e.name.startswith("."))
    except OSError:
        return []
    if suffixes is not None:
        names = [n for n in names if Path(n).suffix in suffixes and (folder / n).is_file()]
    stem = Path(name).stem
    for close in ([n for n in names if Path(n).stem == stem], close_names(name, names, 10, cutoff)):
        kept = [str(folder / n) for n in close if keep is None or keep(folder / n)]
        if kept:
            return kept
    return []


def _kept(
    path: Path, suffixes: tuple[str, ...] | None, keep: Callable[[Path], bool] | None
) -> bool:
    if suffixes is not None and not (path.suffix in suffixes and path.is_file()):
        return False
    return keep is None or keep(path)


def _is_dir(path: Path) -> bool:
    try:
        return path.is_dir()
    except OSError:
        return False


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
