"""What a map records of the encoder that built it, beyond its name and fingerprint:
``encoder_params``, the parameters a config writes beside the name, as a JSON object.

Written by ``quash make-scene`` (and carried by every writer of the encoder record,
``adapters._npz.ENCODER_KEYS``); read back by :func:`recorded_params`; used by
``engine.map_fit`` to say which ``encoder:`` entry to write. Advisory: a record that
cannot be read is ignored, never an error.
"""

from __future__ import annotations

import contextlib
import json
import logging
from typing import Any

from .interfaces import _plain, plugin_name
from .redact import is_secret_param

log = logging.getLogger(__name__)

#: Parameters that never change an encoder's output (docs/plugins.md): not recorded.
OUTPUT_NEUTRAL = ("device", "batch_size")


def recorded_params(source: Any, where: Any = None) -> dict[str, Any] | None:
    """The parameters a map records its encoder was built with (``source["encoder_params"]``,
    a JSON object), or None when it records none or the field is not a JSON object
    (logged at debug level: the record is advisory, never an error)."""
    text = source.get("encoder_params") if isinstance(source, dict) else None
    if text is None:
        return None
    try:
        params = json.loads(text) if isinstance(text, str) else None
    except ValueError as exc:
        params, why = None, f"not JSON ({exc})"
    else:
        why = "not a JSON object"
    if isinstance(params, dict):
        return params
    where = where or (source.get("path") if isinstance(source, dict) else None) or "the map"
    log.debug("%s: encoder_params %.80r is %s; it is ignored", where, text, why)
    return None


def encoder_params(encoder: Any) -> dict[str, Any] | None:
    """The parameters that identify ``encoder``'s output, as a config writes them beside
    its name: its ``config()`` less what its entry point (or class) does not accept,
    ``name``, :data:`OUTPUT_NEUTRAL` (``device``, ``batch_size``), a value that is not plain JSON data, and a key named like a
    credential (``api_key``, ``token``, ``password``: :func:`~quash_plugins.core.redact.is_secret_param`).
    None when it has no ``config()``, or when nothing is left of a config() that names
    parameters other than those it is built with (an empty record would say "built
    with the defaults")."""
    from .registry import accepted_params, load

    config = getattr(encoder, "config", None)
    if not callable(config):
        return None
    try:
        values = config()
    except Exception as exc:  # noqa: BLE001 - advisory: a config() that fails records nothing
        log.debug("encoder %r: config() failed (%s); its parameters are not recorded", encoder, exc)
        return None
    if not isinstance(values, dict):
        return None
    built = type(encoder)
    registered = getattr(encoder, "_quash_plugin_name", None)
    if isinstance(registered, str) and registered:
        # a factory entry point takes its own parameters, not its class's
        with contextlib.suppress(Exception):
            built = load("encoders", registered)
    accepted = accepted_params(built)
    params = {
        k: v
        for k, v in values.items()
        if isinstance(k, str)
        and k not in ("name", *OUTPUT_NEUTRAL)
        and (accepted is None or k in accepted)
        and not is_secret_param(k)
        and _plain(v, written=True)
    }
    if not params and accepted != []:
        log.debug(
            "encoder %r: config() names no parameter it is built with; none recorded",
            plugin_name(encoder),
        )
        return None
    return params
