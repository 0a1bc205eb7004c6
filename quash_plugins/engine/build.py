"""Building a :class:`~quash_plugins.engine.pipeline.Quash` from a config.

This is where a config's names become objects: the plugins through the registry, and
the text-embedding cache from the ``cache`` setting. The pipeline itself is handed
ready objects and never imports a plugin or the cache; a plugin name given to its
constructor (``Quash(enc, heuristic="none")``) is built here by :func:`plugin_argument`.
"""

from __future__ import annotations

import inspect
import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from ..core import registry
from ..core.config import PluginSpec, QuashConfig
from ..core.errors import ConfigError, QuashError, check_options
from .cache import open_cache

log = logging.getLogger(__name__)


class UnavailableEncoder:
    """Stands in for an encoder that could not be built: any use raises why.

    Examples
    --------
    >>> enc = UnavailableEncoder(QuashError("encoder: weights not on this machine"))
    >>> enc.encode(["chair"])
    Traceback (most recent call last):
    ...
    quash_plugins.core.errors.QuashError: encoder: weights not on this machine
    """

    def __init__(self, error: QuashError) -> None:
        self.error = error

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__") or name == "error":
            raise AttributeError(name)
        raise self.error

    def __repr__(self) -> str:
        return f"UnavailableEncoder({str(self.error)!r})"


def build_quash(
    config: str | Path | dict[str, Any] | QuashConfig,
    cls: Any = None,
    *,
    defer_encoder_error: bool = False,
    **overrides: Any,
) -> Any:
    """Build a pipeline from a :class:`QuashConfig`, a dict or a YAML file.

    ``overrides`` replace constructor arguments (e.g. ``cache=None``, ``backend="dask"``);
    an ``encoder``, ``heuristic`` or ``classifier`` override (a name, ``{"name": ...,
    **params}`` or an object) replaces that section, which is then not built.
    Errors name the config file and the section (``encoder``, ``heuristic``...).
    ``defer_encoder_error``: an encoder that cannot be built (weights not on the machine;
    not a misspelt encoder name, which is an error as ever)
    becomes an :class:`UnavailableEncoder` that raises that error when it is used, with a
    warning, so that a heuristic that needs no encoder (``llm``) can still expand a query
    (``quash expand``).

    Examples
    --------
    >>> table = {"chair": [1, 0], "other": [0, 1], "background": [0, 1], "nothing": [0, 1]}
    >>> q = build_quash({"encoder": {"name": "table", "table": table}, "cache": False})
    >>> type(q.classifier).__name__
    'NearestSampleClassifier'
    """
    if cls is None:
        from .pipeline import Quash as cls
    _check_overrides(cls, overrides)
    cfg = QuashConfig.load(config)
    where = f"{cfg.source}: " if cfg.source else ""
    # A plugin given as an override replaces the config's section, which is then not
    # built (the constructor builds a name or a {"name": ...} mapping, as Quash(...) does).
    given = {k: overrides[k] for k in ("encoder", "heuristic", "classifier") if k in overrides}

    def located(text: str) -> bool:
        return bool(cfg.source) and text.startswith(str(cfg.source))

    def build(kind: str, spec: PluginSpec, section: str) -> Any:
        try:
            return build_plugin(kind, spec, section, cfg.device)
        except QuashError as exc:
            # The file and the line of the entry it is about: the plugin's name, the
            # parameter it does not accept, else the section.
            keys = getattr(exc, "keys", (section,))
            raise type(exc)(f"{cfg.location(*keys)}{exc}") from exc.__cause__

    try:
        try:
            if "encoder" in given:
                encoder = given["encoder"]
            else:
                encoder = build("encoders", cfg.encoder, "encoder")
        except QuashError as exc:
            if not defer_encoder_error or _misspelt_encoder(cfg.encoder.name):
                raise
            encoder = UnavailableEncoder(exc if located(str(exc)) else type(exc)(f"{where}{exc}"))
            log.warning(
                "%s (going on without the encoder; a step that needs it stops with this error)",
                encoder.error,
            )
        if "heuristic" in given:
            heuristic = given["heuristic"]
        else:
            heuristic = build("heuristics", cfg.heuristic, "heuristic")
        if "classifier" in given:
            classifier = given["classifier"]
        else:
            classifier = build("classifiers", cfg.classifier, "classifier")
    except QuashError as exc:
        if where and not located(str(exc)):
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
    kwargs.update({k: v for k, v in overrides.items() if k not in given})
    kwargs["cache"] = open_cache(kwargs.get("cache", cfg.cache))
    try:
        quash = cls(encoder, heuristic, classifier, **kwargs)
    except ConfigError as exc:  # refine:, presence: ... checked by the engine
        raise _located(exc, cfg, overrides) from exc.__cause__
    quash.config_source = cfg.source
    quash.config_overrides = frozenset(overrides)
    return quash


def _check_overrides(cls: Any, overrides: dict[str, Any]) -> None:
    """Refuse an override that is no argument of ``cls`` (``treshold=0.2``), naming the
    ones it takes and the closest; it raised TypeError "Quash.__init__() got an
    unexpected keyword argument", after the config's plugins were built."""
    params = inspect.signature(cls.__init__).parameters
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        return
    known = [n for n, p in params.items() if n != "self" and p.kind is not p.VAR_POSITIONAL]
    check_options(f"{cls.__name__}.from_config", overrides, known)


def _misspelt_encoder(name: str) -> bool:
    """True when ``name`` is no registered encoder but is close to one (``minilmm``): a
    typo, an error even where an encoder that cannot be built is put off. A name like no
    registered one may be a plugin this machine lacks, and is put off."""
    from ..core.errors import closest

    known = registry.available("encoders")
    return name not in known and closest(name, known, cutoff=0.8) is not None


def _located(exc: ConfigError, cfg: QuashConfig, overrides: dict[str, Any]) -> ConfigError:
    """``exc`` (about a config section the engine checks) with the config file and line of
    the entry it names (``presence: unknown option 'margn'`` -> ``m.yaml:6: presence:
    ...``); as it was when the section came from ``overrides`` or not from a file."""
    text = str(exc)
    keys = getattr(exc, "keys", None) or (text.split(":", 1)[0],)
    if not cfg.source or keys[0] in overrides or text.startswith(cfg.source):
        return exc
    if not isinstance(keys[0], str) or keys[0] not in cfg.to_dict():
        keys = ()
    return ConfigError(f"{cfg.location(*keys)}{text}")


def build_plugin(
    kind: str, spec: PluginSpec, section: str, device: str = "auto", where: str = ""
) -> Any:
    """Build plugin ``spec`` of ``kind`` through the registry, as a config's ``section``
    is built: a plugin that takes ``device`` and is not given one gets ``device``.
    Errors read ``{where}{section}: ...`` and carry ``keys``, the config entry they are
    about: ``(section, "name")`` for a plugin that cannot be loaded, ``(section, param)``
    for a parameter it does not accept, else ``(section,)``.

    Examples
    --------
    >>> build_plugin("heuristics", PluginSpec("none"), "heuristic").expand("chair").positives
    ['chair']
    """
    params = dict(spec.params)
    keys: tuple[str, ...] = (section, "name")
    try:
        obj = registry.load(kind, spec.name) if spec.name else None
        keys = (section,)
        accepted = registry.accepted_params(obj) if obj is not None else None
        if accepted is not None:
            unknown = [p for p in params if p not in accepted]
            keys = (section, unknown[0]) if unknown else keys
        if "device" not in params and accepted is not None and "device" in accepted:
            params["device"] = device
        return registry.create(kind, spec.name, **params)
    except QuashError as exc:
        # Keep what caused it (a plugin's own import error) for --debug's traceback.
        error = type(exc)(f"{where}{section}: {exc}")
        error.keys = keys  # where a config file says it (QuashConfig.location)
        raise error from exc.__cause__


#: What a plugin argument of :class:`Quash` must have, when it is an object.
_PLUGIN_METHODS = {
    "encoders": ("encode_text",),
    "heuristics": ("expand",),
    "classifiers": ("fit", "get_params"),
}


def plugin_argument(kind: str, section: str, value: Any, device: str) -> Any:
    """A plugin argument of :class:`~quash_plugins.engine.pipeline.Quash`: an object as
    it is; a registered name (``"none"``), a ``{"name": ..., **params}`` mapping or a
    :class:`PluginSpec` built through the registry as a config's ``section`` is (by
    :func:`build_plugin`). Anything else is refused here, naming the argument, rather
    than failing at the first query."""
    if isinstance(value, str):
        value = PluginSpec(value)
    elif isinstance(value, Mapping) and isinstance(value.get("name"), str):
        value = PluginSpec(value["name"], {str(k): v for k, v in value.items() if k != "name"})
    if isinstance(value, PluginSpec):
        return build_plugin(kind, value, section, device, where="Quash: ")
    need = _PLUGIN_METHODS[kind]
    # An encoder that could not be built (UnavailableEncoder) raises on any
    # attribute, so of encoders only None is refused.
    if value is None or (kind != "encoders" and not all(hasattr(value, m) for m in need)):
        raise ConfigError(
            f"Quash: {section} must be an object with {', '.join(need)} or a "
            f"registered name such as {_EXAMPLE[kind]!r}, not {type(value).__name__}; "
            f"`quash plugins --kind {kind}` lists the names."
        )
    return value


_EXAMPLE = {"encoders": "minilm", "heuristics": "none", "classifiers": "svm-rbf"}
