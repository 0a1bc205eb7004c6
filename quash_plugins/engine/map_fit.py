"""Whether a map fits the encoder a query runs with, checked before any work.

- :func:`check_encoder_fits`: the dimensions must agree (else an error naming the fix),
  and a map that records the encoder that built it (``quash make-scene``) warns once
  when another one queries it: a dimension check cannot tell two 384-d encoders apart.
- :func:`warn_if_empty`: an empty map is a warning, not an error.
- :func:`warn_unused_adapter_options`: a config's ``adapter:`` options that a live map
  object (a VLMaps ``VLMap``), which takes its grid from itself, does not use.
"""

from __future__ import annotations

import logging
import warnings
import weakref
from typing import Any

import numpy as np

from ..core.encoder_record import encoder_params, recorded_params
from ..core.errors import DimensionMismatchError, EmptyMapWarning, MapFormatError
from ..core.interfaces import plugin_name, source_digest
from ..core.once import first_time
from ..core.text import encoder_dim
from ..core.types import LatentMap

log = logging.getLogger(__name__)

#: Encoder presets by embedding dimension, suggested on a dimension mismatch.
PRESETS_BY_DIM = {
    384: "minilm (sentence-transformers all-MiniLM-L6-v2)",
    512: "open-clip preset 'lseg' (CLIP ViT-B/32, for LSeg/VLMaps maps)",
    768: "open-clip preset 'openseg' (ViT-L/14@336, for OpenSeg maps)",
    1024: "open-clip preset 'conceptfusion' (ViT-H-14 laion2b, for ConceptFusion maps)",
}

#: (map path, the map's encoder fingerprint, the config's) already warned about.


def check_encoder_fits(encoder: Any, lmap: LatentMap, config_source: Any = None) -> None:
    """Fail when ``encoder``'s dimension differs from ``lmap``'s (naming the encoder the
    map records, when it records one); when they agree, warn (once per map and encoder)
    when the map records that another encoder built it.

    ``config_source``: the config file the encoder came from, named in the error.
    """
    enc_dim = encoder_dim(encoder)
    if enc_dim == lmap.dim:
        warn_built_by(encoder, lmap)
        return
    from ..core.registry import accepted_params

    where = lmap.source.get("path", "the map")
    name = plugin_name(encoder)  # what the config's encoder section calls it
    section = f" (the 'encoder:' section of {config_source})" if config_source else ""
    built = lmap.source.get("encoder")
    recorded = recorded_params(lmap.source)
    fixes = []
    if (
        isinstance(built, str)
        and built
        and built not in (name, getattr(encoder, "name", None))
        and not _same_plugin(built, name)
    ):
        # The map names the encoder that built it: that is the fix, not another dim of
        # this one (which would only give rows of the right length in another space).
        fix = f"the map records that encoder {built!r} built it"
        if _registered_encoder(built):
            if recorded is not None:
                fix += f": write 'encoder: {config_entry(built, recorded)}'"
            else:
                fix += f": write 'encoder: {built}' with the parameters the map was built with"
        else:  # a class name no entry point registers, or a name two distributions claim
            fix += f" (fingerprint {lmap.source.get('encoder_fingerprint', '?')}): query with it"
        fixes.append(fix)
    elif recorded is not None:
        # the map's own encoder, built with other parameters: the map says which
        fixes.append(
            f"write 'encoder: {config_entry(name, recorded)}' (the parameters the map "
            "records it was built with)"
        )
    else:
        if "dim" in (accepted_params(type(encoder)) or []):
            fixes.append(
                f"set 'encoder: {{name: {name}, dim: {lmap.dim}}}' if that model supports it"
            )
        hint = PRESETS_BY_DIM.get(lmap.dim)
        if hint:
            fixes.append(f"a matching encoder: {hint}")
    text = "; or ".join(fixes)
    suggestion = f" {text[0].upper()}{text[1:]}." if text else ""
    note = lmap.source.get("dim_note")  # the adapter's word on how it read D
    note = f" ({note})" if isinstance(note, str) and note else ""
    raise DimensionMismatchError(
        f"{where} has {lmap.dim}-dimensional embeddings{note}, but encoder "
        f"{name!r}{section} produces {enc_dim}-dimensional ones. Use the text "
        f"encoder that built the map.{suggestion}"
    )


def config_entry(name: str, params: dict[str, Any]) -> str:
    """The ``encoder:`` entry of a config that builds ``name`` with ``params``, in YAML
    flow style (``{name: bag-of-words, dim: 64}``; the bare name without parameters),
    valid to paste after ``encoder:``."""
    import yaml

    if not params:
        return _flow(name)
    entry = {"name": name, **{k: v for k, v in params.items() if k != "name"}}
    text = yaml.safe_dump(entry, default_flow_style=True, sort_keys=False, width=float("inf"))
    return text.strip()


def _param_differences(recorded: dict[str, Any], encoder: Any) -> str | None:
    """The parameters the map records that ``encoder`` (the config's) has otherwise,
    as ``dim: 64 (the map) vs 32 (this config)``; "" when none differs, None when the
    config's encoder names none."""
    ours = encoder_params(encoder)
    if ours is None:
        return None
    missing = object()
    parts = []
    for key in [*recorded, *(k for k in ours if k not in recorded)]:
        theirs, mine = recorded.get(key, missing), ours.get(key, missing)
        if theirs == mine and type(theirs) is type(mine):
            continue
        parts.append(
            f"{key}: {'(not recorded)' if theirs is missing else _flow(theirs)} (the map) "
            f"vs {'(not set)' if mine is missing else _flow(mine)} (this config)"
        )
    return "; ".join(parts)


def _flow(value: Any) -> str:
    """``value`` as YAML writes it in a config (``64``, ``true``, ``[a, b]``)."""
    import yaml

    text = yaml.safe_dump(value, default_flow_style=True, width=float("inf"))
    return text.removesuffix("\n...\n").strip()


def _registered_encoder(name: str) -> bool:
    """Whether a config can write ``encoder: name`` (a registered encoder has that name,
    or that ``dist:name``). Looked up without resolving it, so a name that a plugin
    shadows is not warned about here: this config does not use it."""
    return bool(_claims(name))


def _claims(spelled: str) -> set[str]:
    """The registered encoders ``spelled`` names: a bare name, or ``dist:name`` with the
    distribution written as pip writes it or as its import name (``my_pkg:x`` is
    ``my-pkg:x``, as the registry resolves it)."""
    from ..core.registry import _same_dist, plugins

    dist, sep, short = spelled.partition(":")
    if not sep:
        dist, short = "", spelled
    return {
        i.qualified
        for i in plugins("encoders")
        if i.name == short and (not dist or _same_dist(i.dist, dist))
    }


def _same_plugin(built: str, name: str) -> bool:
    """Whether the map's record ``built`` and the config's ``name`` are two spellings of
    one registered encoder ('dist:name' and the bare name). Looked up without resolving,
    as :func:`_registered_encoder`; a bare name two distributions claim is no match."""
    ours = _claims(name)
    return len(ours) == 1 and _claims(built) == ours


def same_embedding_function(encoder: Any, fingerprint: str) -> bool:
    """Whether ``fingerprint`` names ``encoder``'s embedding function: its fingerprint
    now, or one an earlier version gave the same function (``earlier_fingerprints``,
    asked only when the current one differs). An encoder without a fingerprint names
    nothing, so nothing is said to differ."""
    ours = getattr(encoder, "fingerprint", None)
    if not callable(ours) or fingerprint == ours():
        return True
    earlier = getattr(encoder, "earlier_fingerprints", None)
    return callable(earlier) and fingerprint in earlier()


def warn_built_by(encoder: Any, lmap: LatentMap) -> None:
    """Warn once per map and encoder when ``lmap.source`` records another encoder's
    fingerprint (``encoder_fingerprint``) than ``encoder``'s."""
    built = lmap.source.get("encoder_fingerprint")
    if not isinstance(built, str) or not built or same_embedding_function(encoder, built):
        return
    ours = encoder.fingerprint()
    if not first_time(("built-by", str(lmap.source.get("path")), built, ours)):
        return
    name = plugin_name(encoder)  # what the config's encoder section calls it
    built_name = lmap.source.get("encoder", "?")
    recorded = recorded_params(lmap.source)
    entry = ""  # the config's encoder entry that builds the map's encoder, when known
    # A map may record either name: the registered one, or the instance's ``name``.
    # 'dist:name' is another distribution's plugin than the bare name: a map that
    # records the bare name was not built with it
    qualified = ":" in name
    if (
        built_name == name
        or (not qualified and built_name == getattr(encoder, "name", None))
        or (isinstance(built_name, str) and _same_plugin(built_name, name))
    ):
        differs = (
            f"this config's {name!r} is another embedding function ({ours}): other weights, "
            "another model or other settings (normalize, dim, templates) under the same "
            "encoder name"
        )
        if source_digest(type(encoder)) is not None:
            # An editable install or a local module: its fingerprint hashes its source.
            differs += (
                f", or its code: {name!r} is an editable install or a local module, whose "
                "fingerprint hashes its package's .py files, so any edit since the map was "
                "built counts"
            )
        else:
            from ..core.registry import distribution_of

            release = distribution_of(type(encoder).__module__)
            if release is not None and not type(encoder).__module__.startswith("quash_plugins"):
                differs += (
                    f", or another release of its distribution (now {release}): the "
                    "fingerprint covers the version, so a map built before an upgrade counts"
                )
        changed = None if recorded is None else _param_differences(recorded, encoder)
        if changed:
            differs += f". The parameters that differ: {changed}"
            entry = config_entry(name, recorded)
        elif changed == "":
            differs += (
                f". The parameters the map records ({config_entry(name, recorded)}) "
                "are this config's, so the difference is not in them"
            )
    else:
        differs = f"this config's encoder is {name!r} ({ours})"
        if recorded is not None and isinstance(built_name, str) and _registered_encoder(built_name):
            entry = config_entry(built_name, recorded)
    fix = "query with the encoder that built the map"
    if entry:
        fix += f" ('encoder: {entry}')"
    log.warning(
        "%s was built with encoder %r (fingerprint %s), but %s. Scores mean something only "
        "when both embed text into the same space: %s.",
        lmap.source.get("path", "the map"),
        built_name,
        built,
        differs,
        fix,
    )


def warn_if_empty(lmap: LatentMap) -> None:
    """Warn (:class:`~quash_plugins.core.errors.EmptyMapWarning`) when ``lmap`` has no items.

    Upstream mappers write empty maps when nothing was fused; a query on one is an empty
    result, not an error.
    """
    if lmap.n == 0:
        where = lmap.source.get("path", "the map")
        warnings.warn(
            f"{where} is empty (0 items x {lmap.dim}): nothing was fused into it, so every "
            "query matches nothing.",
            EmptyMapWarning,
            stacklevel=3,
        )


def option_source(
    exc: MapFormatError,
    spec: Any,
    config_source: str | None,
    given: dict[str, Any] | None,
    origin: str | None = None,
) -> MapFormatError:
    """``exc`` (a map read's error) with where an option it names came from, when that
    was the config's ``adapter:`` section (``spec``) rather than the command (``-o``) or
    the call (``given``; None: the section was not used): a user who never passed ``cs``
    is told which file to change. ``origin`` names where ``spec`` came from instead of
    the section (``Quash.from_config(adapter=...)``)."""
    if given is None:
        return exc
    text = str(exc)
    named = [
        f"{key}={value!r}"
        for key, value in (getattr(spec, "params", None) or {}).items()
        if key not in given and (f"option {key}=" in text or f"option {key!r}" in text)
    ]
    if not named:
        return exc
    where = f" of {config_source}" if config_source else ""
    origin = origin or f"the adapter: section{where}"
    return MapFormatError(
        f"{text} ({', '.join(named)} comes from {origin}: change or remove it there.)"
    )


#: Per live map object, the adapter options already warned about.
_ADAPTER_WARNED: weakref.WeakKeyDictionary[Any, set] = weakref.WeakKeyDictionary()


def warn_unused_adapter_options(
    spec: Any, lmap: LatentMap, obj: Any, read_options: dict[str, Any]
) -> None:
    """Log once per live map object each option of the config's ``adapter:`` section
    (``spec``, a ``PluginSpec``) that the object does not use and that disagrees with it:
    a live map's values come from the object, and only ``read_options`` (given to the
    query) override them."""
    params = dict(getattr(spec, "params", None) or {})
    try:  # remembered beside the object, never on it (the user's VLMap stays as it was)
        warned = _ADAPTER_WARNED.setdefault(obj, set())
    except TypeError:  # an object that cannot be weakly referenced: warn each time
        warned = set()
    for key, value in params.items():
        if key in read_options:
            continue  # passed to the live map's adapter, so it does apply
        live = lmap.source.get(key)
        if live is not None and _same(value, live):
            continue
        tag = (key, repr(value))
        if tag in warned:
            continue
        warned.add(tag)
        has = f"the live map has {key} = {live!r}" if live is not None else "it is not used"
        log.warning(
            "the config's adapter section (%s: %r) does not apply to the live %s object; %s. A live "
            "map's gs, cs and pose type come from the object itself (its grid and map "
            "config); pass query(vlmap, ..., %s=...) to override, or drop it from the "
            "config's adapter section.",
            key,
            value,
            type(obj).__name__,
            has,
            key,
        )


def _same(a: Any, b: Any) -> bool:
    try:
        return bool(np.isclose(float(a), float(b), rtol=1e-6, atol=0))
    except (TypeError, ValueError):
        return a == b
