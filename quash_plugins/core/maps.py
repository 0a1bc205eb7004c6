"""Reading a map with the adapter that recognises it (``adapter="auto"``) or by name.

These know no adapter by name: they ask every registered adapter through the registry,
so a third-party adapter is detected exactly as a built-in one is.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from . import registry
from .errors import MapFormatError, PluginError
from .types import LatentMap

log = logging.getLogger(__name__)


def detect_adapter(source: Any) -> str:
    """Name of the first registered adapter whose ``sniff`` accepts ``source``.

    Adapters are tried in order of their ``priority`` attribute (highest first), then name.
    """
    candidates = []
    for name in registry.available("adapters"):
        try:
            cls = registry.load("adapters", name)
        except PluginError as exc:
            log.debug("skipping adapter %s: %s", name, exc)
            continue
        candidates.append((-int(getattr(cls, "priority", 0)), name, cls))
    for _, name, cls in sorted(candidates, key=lambda c: (c[0], c[1])):
        try:
            if cls().sniff(source):
                return name
        except Exception as exc:  # noqa: BLE001 - a faulty sniff must not break detection
            log.debug("adapter %s failed to sniff %r: %s", name, source, exc)
    what = str(source) if isinstance(source, (str, Path)) else type(source).__name__
    raise MapFormatError(
        f"No adapter recognises {what}. Known adapters: "
        f"{', '.join(registry.available('adapters'))}. Pass --adapter NAME to choose one."
    )


def resolve_adapter(source: Any, adapter: str | None = "auto") -> tuple[Any, str]:
    """``(source, name)``: a path source checked and expanded, ``"auto"`` resolved by sniffing.

    Raises :class:`MapFormatError` for a path that does not exist.
    """
    if isinstance(source, (str, Path)):
        path = Path(source).expanduser()
        if not path.exists():
            raise MapFormatError(f"Map not found: {path}. Check the path.")
        source = path
    name = detect_adapter(source) if adapter in (None, "auto") else str(adapter)
    return source, name


def read_map(source: Any, adapter: str = "auto", **options: Any) -> LatentMap:
    """Read ``source`` (path or live object) into a :class:`LatentMap`, read-only."""
    if isinstance(source, LatentMap):
        return source
    source, name = resolve_adapter(source, adapter)
    reader = registry.create("adapters", name, **options)
    lmap = reader.read(source)
    if not isinstance(lmap, LatentMap):
        raise PluginError(f"Adapter {name!r} returned {type(lmap).__name__}, not a LatentMap.")
    lmap.source.setdefault("adapter", name)
    if isinstance(source, Path):
        lmap.source.setdefault("path", str(source))
    log.info("read %s", lmap.describe())
    return lmap
