"""Entry-point discovery: the plugin groups, what is installed in them, and entry points
placed in a group quash-plugins does not read.

Listing reads distribution metadata only; nothing is imported here. Private to
:mod:`quash_plugins.core`; :mod:`quash_plugins.core.registry` re-exports the public names
(``KINDS``, ``BUILTIN_DIST``, ``GROUP_PREFIX``, ``PluginInfo``, ``MisplacedEntryPoint``,
``misplaced_entry_points``) and builds the registry API on :func:`scan`.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from importlib import metadata
from typing import Any

from ._distributions import distribution_is_editable, note_distribution

KINDS: tuple[str, ...] = ("encoders", "heuristics", "classifiers", "adapters")
#: The distribution of the built-in plugins; they keep their bare names.
BUILTIN_DIST = "quash-plugins"
GROUP_PREFIX = "quash_plugins."


@dataclass
class PluginInfo:
    """One registered plugin, as listed by ``quash plugins``."""

    kind: str
    name: str
    target: str
    dist: str
    version: str
    status: str = "not loaded"
    error: str | None = None
    _loader: Callable[[], Any] | None = field(default=None, repr=False)
    _obj: Any = field(default=None, repr=False)
    #: The exception raised while importing or validating the plugin (for ``--debug``).
    exception: BaseException | None = field(default=None, repr=False)
    #: The installed distribution whose entry point this is (None when registered in
    #: the process with :func:`~quash_plugins.core.registry.register`).
    _distribution: metadata.Distribution | None = field(default=None, repr=False)

    @property
    def qualified(self) -> str:
        return f"{self.dist}:{self.name}"

    @property
    def editable(self) -> bool:
        """True when the plugin's distribution is an editable install (``pip install
        -e``) or a source tree found first (:func:`~quash_plugins.core.registry.
        distribution_is_editable`): its version does not name its code. False for a
        released install and for a plugin registered in the process."""
        if self._distribution is None:
            return False
        return distribution_is_editable(self._distribution)

    def to_dict(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "name": self.name,
            "target": self.target,
            "distribution": self.dist,
            "version": self.version,
            "editable": self.editable,
            "status": self.status,
            "error": self.error,
        }


_lock = threading.RLock()
_scanned: dict[str, list[PluginInfo]] = {}


def scan(kind: str) -> list[PluginInfo]:
    with _lock:
        if kind in _scanned:
            return _scanned[kind]
        infos: list[PluginInfo] = []
        for ep in metadata.entry_points(group=GROUP_PREFIX + kind):
            dist = getattr(ep, "dist", None)
            dist_name = dist.metadata["Name"] if dist is not None else "<unknown>"
            version = dist.version if dist is not None else "?"
            # The same distribution can be visible twice on sys.path (e.g. an editable
            # install plus a source checkout): keep one entry per (dist, name).
            if any(i.name == ep.name and i.dist == dist_name for i in infos):
                continue
            infos.append(
                PluginInfo(
                    kind, ep.name, ep.value, dist_name, version, _loader=ep.load, _distribution=dist
                )
            )
            if dist is not None:
                note_distribution(ep.value, dist_name, version)
        _scanned[kind] = infos
        return infos


@dataclass
class MisplacedEntryPoint:
    """An entry point in a group quash-plugins does not read, but whose name says it
    was meant for one (``quash_plugins.encoder``, ``quash-plugins.encoders``...)."""

    group: str
    name: str
    target: str
    dist: str
    #: The group it was most likely meant for, else None.
    meant: str | None

    def message(self) -> str:
        groups = (
            repr(self.meant)
            if self.meant
            else "one of " + ", ".join(repr(GROUP_PREFIX + k) for k in KINDS)
        )
        return (
            f"Distribution {self.dist!r} registers {self.name!r} ({self.target}) in the "
            f"entry-point group {self.group!r}, which quash-plugins does not read: move it "
            f"to {groups} in the pyproject.toml of {self.dist!r} and reinstall it."
        )


def misplaced_entry_points() -> list[MisplacedEntryPoint]:
    """Entry points in a group named like quash-plugins' but not one of its groups.

    Such a plugin is otherwise invisible: ``quash plugins`` does not list it and a
    config that names it is told only that the name is not registered.
    """
    known = {GROUP_PREFIX + k for k in KINDS}
    out: list[MisplacedEntryPoint] = []
    seen: set[tuple[str, str, str]] = set()
    for dist in metadata.distributions():
        for ep in dist.entry_points:
            group = ep.group
            norm = group.lower().replace("-", "_").replace(" ", "")
            if group in known or not norm.startswith("quash"):
                continue
            rest = norm.removeprefix("quash").lstrip("._:")
            ours = rest.startswith("plugin")  # quash_plugins, quash.plugins, quashplugin...
            rest = rest.removeprefix("plugins").removeprefix("plugin").strip("._:")
            meant = next((GROUP_PREFIX + k for k in KINDS if rest and rest in (k, k[:-1])), None)
            if not ours and meant is None:
                continue  # another project's 'quash...' group; 'quash.encoders' is ours
            key = (group, ep.name, dist.metadata["Name"])
            if key not in seen:
                seen.add(key)
                out.append(MisplacedEntryPoint(group, ep.name, ep.value, key[2], meant))
    return out
