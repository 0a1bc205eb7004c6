"""Building a :class:`~quash_plugins.engine.pipeline.Quash` from a config.

This is where a config's names become objects: the plugins through the registry, and
the text-embedding cache from the ``cache`` setting. The pipeline itself is handed
ready objects and never imports a plugin or the cache.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..core import registry
from ..core.config import PluginSpec, QuashConfig
from ..core.errors import QuashError
from .cache import open_cache


def build_quash(
    config: str | Path | dict[str, Any] | QuashConfig, cls: Any = None, **overrides: Any
) -> Any:
    """Build a pipeline from a :class:`QuashConfig`, a dict or a YAML file.

    ``overrides`` replace constructor arguments (e.g. ``cache=None``, ``backend="dask"``).
    Errors name the config file and the section (``encoder``, ``heuristic``...).

    Examples
    --------
    >>> table = {"chair": [1, 0], "other": [0, 1], "background": [0, 1], "nothing": [0, 1]}
    >>> q = build_quash({"encoder": {"name": "table", "table": table}, "cache": False})
    >>> type(q.classifier).__name__
    'NearestSampleClassifier'
    """
    if cls is None:
        from .pipeline import Quash as cls
    cfg = QuashConfig.load(config)
    where = f"{cfg.source}: " if cfg.source else ""

    def build(kind: str, spec: PluginSpec, section: str) -> Any:
        params = dict(spec.params)
        obj = registry.load(kind, spec.name) if spec.name else None
        accepted = registry.accepted_params(obj) if obj is not None else None
        if "device" not in params and accepted is not None and "device" in accepted:
            params["device"] = cfg.device
        try:
            return registry.create(kind, spec.name, **params)
        except QuashError as exc:
            # Keep what caused it (a plugin's own import error) for --debug's traceback.
            raise type(exc)(f"{where}{section}: {exc}") from exc.__cause__

    try:
        encoder = build("encoders", cfg.encoder, "encoder")
        heuristic = build("heuristics", cfg.heuristic, "heuristic")
        classifier = build("classifiers", cfg.classifier, "classifier")
    except QuashError as exc:
        if where and not str(exc).startswith(where):
            raise type(exc)(f"{where}{exc}") from exc.__cause__
        raise
    kwargs: dict[str, Any] = dict(
        negatives=cfg.negatives,
        threshold=cfg.threshold,
        prompt_templates=cfg.prompt_templates,
        map_negatives=cfg.map_negatives,
        refine=cfg.refine,
        presence=cfg.presence,
        adapter=cfg.adapter,
        instances=cfg.instances,
        seed=cfg.seed,
        chunk_mb=cfg.chunk_mb,
        name=cfg.name,
        device=cfg.device,
    )
    kwargs.update(overrides)
    kwargs["cache"] = open_cache(kwargs.get("cache", cfg.cache))
    quash = cls(encoder, heuristic, classifier, **kwargs)
    quash.config_source = cfg.source
    return quash
