"""Reading a map for :class:`~quash_plugins.engine.pipeline.Quash`.

:func:`read_map` is the body of :meth:`Quash.read_map
<quash_plugins.engine.pipeline.Quash.read_map>`: the adapter a source is read with, the
config's ``adapter:`` options, the maps kept for reuse and the errors that name where an
option came from. :func:`check_adapter_section` checks the config's ``adapter:`` section
as the config's. The pipeline imports ``_none_ref`` from here under its old name.
"""

from __future__ import annotations

from typing import Any

from ..core import registry
from ..core.config import PluginSpec
from ..core.errors import ConfigError, MapFormatError
from ..core.types import LatentMap
from .map_fit import option_source, warn_unused_adapter_options


def read_map(quash: Any, source: Any, adapter: str | None, options: dict[str, Any]) -> LatentMap:
    """:meth:`Quash.read_map <quash_plugins.engine.pipeline.Quash.read_map>` of ``quash``."""
    from ..core.maps import live_adapter, read_map, resolve_adapter

    if isinstance(source, LatentMap):
        return source
    name = adapter or quash.adapter.name
    live = live_adapter(source, name) if adapter is None and name != "auto" else None
    if live is not None:
        lmap = quash.read_map(source, live, **options)
        warn_unused_adapter_options(quash.adapter, lmap, source, options)
        return lmap
    if name in (None, "auto"):
        # Resolve "auto" first, so the options the config gives for the adapter it
        # picks (or for "auto" itself) apply.
        source, name = resolve_adapter(source, name)
    configured = quash.adapter.name in (name, "auto")
    opts = {**quash.adapter.params, **options} if configured else options
    if configured and quash.adapter.params:
        quash._check_adapter_section(name)
    kept, token = quash._maps.lookup(source, name, opts)
    if kept is not None:
        return kept
    try:
        lmap = read_map(source, name, **opts)
    except MapFormatError as exc:
        given = options if configured else None
        origin = (
            "the adapter= argument of Quash.from_config"
            if "adapter" in quash.config_overrides
            else None
        )
        raise option_source(exc, quash.adapter, quash.config_source, given, origin) from None
    quash._maps.store(token, lmap, quash.keep_maps)
    # the query sets of maps that are gone go too (here, not on every expand)
    for k in [k for k, (r, _) in quash._querysets.items() if k[1] and r() is None]:
        del quash._querysets[k]
    return lmap


def check_adapter_section(
    adapter: PluginSpec, name: str, config_source: str | None, overrides: frozenset[str]
) -> None:
    """Build adapter ``name`` with the config's own ``adapter:`` options, so that a bad
    one is reported as the config's (``q.yaml: adapter: ...``), not the command's."""
    try:
        registry.create("adapters", name, **adapter.params)
    except ConfigError as exc:
        if "adapter" in overrides:
            raise ConfigError(f"Quash.from_config(adapter=...): {exc}") from None
        where = f"{config_source}: " if config_source else ""
        raise ConfigError(f"{where}adapter: {exc}") from None


def _none_ref() -> None:
    """The weak reference of the query sets expanded without a map."""
    return None
