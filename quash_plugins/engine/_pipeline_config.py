"""The configuration side of :class:`~quash_plugins.engine.pipeline.Quash`.

Its constructor's argument checks (prompt templates, adapter, instances, cache,
``chunk_mb``, backend and client), its one-line description, the checks on what a
heuristic returns, the provenance a query set gets from the prompt templates and the
``-v`` log line of a query set. :mod:`quash_plugins.engine.pipeline` imports
``BACKENDS``, ``_check_chunk_mb`` and ``_queryset_words`` from here, under the names
they had there.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from ..core.config import PluginSpec
from ..core.errors import ConfigError, QuashError
from ..core.interfaces import plugin_name
from ..core.text import resolve_templates
from ..core.types import QuerySet

#: The backends a Quash takes (None and "local": the in-memory pass, as "numpy").
BACKENDS = ("numpy", "local", "dask", None)


def check_prompt_templates(prompt_templates: dict[str, Any] | None) -> tuple[Any, str | None]:
    """The templates and where they came from (``(None, None)`` without templates);
    an unknown key or a ``normalize`` that is not a bool is refused."""
    if prompt_templates is None:
        return None, None
    unknown = set(prompt_templates) - {"mode", "templates", "normalize"}
    if unknown:
        raise ConfigError(
            f"prompt_templates does not accept {sorted(unknown)}; it takes mode, "
            "templates and normalize."
        )
    if not isinstance(prompt_templates.get("normalize", True), bool):
        raise ConfigError("prompt_templates: normalize must be true or false.")
    return resolve_templates(prompt_templates.get("templates", "default"))


def adapter_spec(adapter: str | Mapping[str, Any] | PluginSpec) -> PluginSpec:
    """The ``adapter`` argument as a :class:`PluginSpec`: a name, the config's form
    ``{name: vlmaps, cs: 0.05}`` (its options apply to ``read_map``) or a spec."""
    if isinstance(adapter, Mapping) and isinstance(adapter.get("name"), str):
        adapter = PluginSpec(adapter["name"], {k: v for k, v in adapter.items() if k != "name"})
    return adapter if isinstance(adapter, PluginSpec) else PluginSpec(str(adapter))


def instance_options(instances: dict[str, Any] | bool | None) -> dict[str, Any] | None:
    """The options of instance grouping: True for defaults, None/False to skip it."""
    if instances is True:
        instances = {}
    return dict(instances) if isinstance(instances, dict) else None


def check_cache(cache: Any) -> Any:
    """The text-embedding cache object, or None; ``cache=True`` is refused (a config's
    ``cache: true`` is :meth:`Quash.from_config`'s to open)."""
    if cache is True or cache is False:
        if cache:
            raise ConfigError(
                "Quash(cache=True): pass a cache object, e.g. "
                "quash_plugins.engine.TextEmbeddingCache(), or build with "
                "Quash.from_config (which opens the default cache for 'cache: true')."
            )
        return None
    return cache


def check_backend(backend: Any, client: Any) -> None:
    """Refuse an unknown backend, and a client given as its address."""
    if backend not in BACKENDS:
        raise ConfigError(
            f"Unknown backend {backend!r}. Known: {', '.join(b for b in BACKENDS if b)}."
        )
    if isinstance(client, str):
        raise ConfigError(
            f"client={client!r}: pass a dask.distributed.Client, e.g. "
            f"Client({client!r}), not its address (quash --scheduler ADDRESS connects "
            "on the command line)."
        )


def _check_chunk_mb(value: Any) -> float:
    """``chunk_mb`` as a float, refused unless positive and finite (as a config's is)."""
    try:
        out = float(value)
    except (TypeError, ValueError):
        out = math.nan
    if not (math.isfinite(out) and out > 0):
        raise ConfigError(f"chunk_mb must be a positive, finite number of MiB; got {value!r}.")
    return out


def describe(quash: Any) -> str:
    """``Quash(name=..., ...)``: the config's name and the plugins and stages that answer
    a query (``refine`` names the re-fitted classifier; ``presence`` is on or off)."""
    refine = quash.refine.classifier if quash.refine is not None else None
    if isinstance(refine, dict):
        refine = refine.get("name")
    parts = [
        f"name={quash.name!r}",
        f"encoder={plugin_name(quash.encoder)!r}",
        f"heuristic={plugin_name(quash.heuristic)!r}",
        f"classifier={plugin_name(quash.classifier)!r}",
        f"refine={str(refine) if refine is not None else None!r}",
        f"presence={'on' if quash.presence is not None else 'off'!r}",
        f"backend={quash.backend!r}",
        f"device={quash.device!r}",
    ]
    return f"Quash({', '.join(parts)})"


def check_queryset(qs: Any, heuristic: Any, text: str, negatives: Sequence[str]) -> QuerySet:
    """What ``heuristic`` returned for ``text``, with the generic ``negatives`` added;
    refused unless a :class:`QuerySet` that has negatives."""
    if not isinstance(qs, QuerySet):
        raise QuashError(
            f"Heuristic {plugin_name(heuristic)!r} returned {type(qs).__name__}, not a QuerySet."
        )
    qs = qs.with_negatives(negatives)
    if not qs.negatives:
        raise QuashError(
            f"Query set for {text!r} has no negatives; configure 'negatives' or a heuristic "
            "that produces antonyms."
        )
    return qs


def templates_provenance(
    prompt_templates: dict[str, Any], templates: Sequence[str] | None, source: str | None
) -> dict[str, Any]:
    """What a query set's provenance says of the prompt templates it was embedded with."""
    return {
        "mode": prompt_templates.get("mode", "mean"),
        "count": len(templates or []),
        "source": source,
        "normalize": bool(prompt_templates.get("normalize", True)),
    }


def _queryset_words(qs: QuerySet, limit: int = 24) -> str:
    """``heuristic (source); N positives: a, b, ...; M negatives: ...``, each list cut at
    ``limit`` names (the log line of ``-v``)."""

    def head(words: Sequence[str]) -> str:
        shown = ", ".join(words[:limit])
        return shown + (f", ... and {len(words) - limit} more" if len(words) > limit else "")

    prov = qs.provenance or {}
    how = str(prov.get("heuristic", "?"))
    if prov.get("source"):  # llm: server or cache
        how += f" from {prov['source']}"
    return (
        f"{how}; {len(qs.positives)} positives: {head(qs.positives)}; "
        f"{len(qs.negatives)} negatives: {head(qs.negatives)}"
    )
