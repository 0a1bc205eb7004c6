"""The conformance kit's encoder checks: output, determinism (within a process, across
instances and across processes), batch independence, empty input, the empty string, and
a fingerprint that is stable and follows the parameters that change the output."""

from __future__ import annotations

import weakref
from pathlib import Path
from typing import Any

import numpy as np

from ..core.encoder_record import OUTPUT_NEUTRAL


def check_encoder_output(enc: Any, tmp_path: Path) -> None:
    dim = enc.dim
    assert isinstance(dim, (int, np.integer)) and dim > 0, (
        f"dim must be a positive int; got {dim!r}"
    )
    texts = ["chair", "a red chair", "kitchen sink"]
    e = enc.encode_text(texts)
    assert e is not None, "encode_text returned None: return the array it computes"
    assert isinstance(e, np.ndarray), (
        f"encode_text must return a numpy array; got {type(e).__module__}.{type(e).__name__} "
        + (
            "(a torch tensor: return .detach().float().cpu().numpy())"
            if callable(getattr(e, "detach", None))
            else "(return np.asarray(rows, dtype=np.float32))"
        )
    )
    assert e.shape == (3, dim), (
        f"encode_text shape {e.shape}, expected (3, {dim}): one row of dim = {dim} numbers "
        "per text (dim is the property the map's dimension is checked against: make it say "
        "what encode_text returns)"
    )
    _one_row(enc)
    assert e.dtype == np.float32, (
        f"encode_text dtype {e.dtype}, expected float32: return rows.astype(np.float32)"
    )
    _unit_rows(e, texts)


def _unit_rows(e: np.ndarray, texts: list[str]) -> None:
    """``e``'s rows, one per text of ``texts``, are finite and of unit L2 norm; else a
    failure naming the first text that is not, and the fix."""
    finite = np.isfinite(e).all(axis=1)
    if not finite.all():
        bad = texts[int(np.argmin(finite))]
        raise AssertionError(
            f"encode_text returned NaN/Inf for {bad!r}: a row of zeros divided by its norm "
            "is NaN, so give every text at least one nonzero component (as the example "
            "does with `text.split() or ['']`) before normalising"
        )
    norms = np.linalg.norm(e.astype(np.float64), axis=1)
    off = np.abs(norms - 1.0) > 1e-3
    if off.any():
        i = int(np.argmax(np.abs(norms - 1.0)))
        raise AssertionError(
            f"rows must be L2-normalised: {int(off.sum())} of {len(norms)} rows are not "
            f"(the row of {texts[i]!r} has norm {norms[i]:.4g}); divide each row by its "
            "own norm: rows / np.linalg.norm(rows, axis=1, keepdims=True)"
        )


def _one_row(enc: Any) -> np.ndarray:
    """``enc``'s rows for one text, which must be ``(1, dim)`` like any other batch."""
    e = np.asarray(enc.encode_text(["table"]))
    assert e.shape == (1, enc.dim), (
        f"encode_text(['table']) shape {e.shape}, expected (1, {enc.dim}): return one row "
        "per text for one text too (no squeeze(), no [0]): a query whose other texts are "
        "cached asks for one"
    )
    return e


def check_encoder_deterministic(enc: Any, tmp_path: Path) -> None:
    a = np.asarray(enc.encode_text(["chair", "table"]))
    b = np.asarray(enc.encode_text(["chair", "table"]))
    assert np.allclose(a, b, atol=1e-5), (
        "encode_text must be deterministic: the same texts gave embeddings differing by "
        f"up to {float(np.abs(a - b).max()):.3g}. Embeddings are cached on disk by text, "
        "so draw any randomness from a fixed seed or from the text itself, never from the "
        "global random state (and put the model in eval mode: no dropout)."
    )
    # Another instance with the same fingerprint (another process: the query after the
    # map was built, the text cache) must give the same rows too.
    other = _rebuilt(enc)
    if other is None:
        return
    try:
        c = np.asarray(other.encode_text(["chair", "table"]))
    except Exception:  # noqa: BLE001 - weights it cannot load twice: not this check's
        return
    assert c.shape == a.shape and np.allclose(a, c, atol=1e-5), (
        "encode_text must be the same function in every instance with the same "
        f"fingerprint(): a second {type(enc).__name__} built with the same parameters "
        "embedded the same texts differently"
        + (f" (by up to {float(np.abs(a - c).max()):.3g})" if c.shape == a.shape else "")
        + ". Embeddings are cached on disk by fingerprint and a map is queried in another "
        "process than the one that built it, so seed any random initialisation (a "
        "projection drawn in __init__) with a parameter that config() returns."
    )


def _rebuilt(enc: Any) -> Any:
    """A second instance of ``enc``'s class built with the parameters ``enc`` holds,
    when it has the same fingerprint; else None (parameters that cannot be known)."""
    found = _varied_params(enc)
    if found is None:
        return None
    try:
        other = type(enc)(**found[0])
        return other if other.fingerprint() == enc.fingerprint() else None
    except Exception:  # noqa: BLE001 - a value it refuses, or weights it cannot load
        return None


#: What the other process of :func:`check_encoder_same_in_another_process` runs: build
#: the class from its module with the same parameters, embed, save the rows.
_OTHER_PROCESS = """
import importlib, json, sys
import numpy as np
spec = json.loads(sys.stdin.read())
sys.path[:0] = [p for p in spec["path"] if p not in sys.path]
obj = importlib.import_module(spec["module"])
for part in spec["qualname"].split("."):
    obj = getattr(obj, part)
rows = obj(**spec["params"]).encode_text(spec["texts"])
np.save(spec["out"], np.asarray(rows, dtype=np.float32))
"""


def check_encoder_same_in_another_process(enc: Any, tmp_path: Path) -> None:
    """The same class and parameters embed the same in another Python process, as the
    text cache and a map queried after it was built assume. Python salts ``hash()`` of a
    string per process (``PYTHONHASHSEED``), so an encoder that seeds from ``hash(text)``
    or walks a set of strings passes every check within one process and differs in the
    next. Skipped for a class another process cannot import (defined in a function or in
    ``__main__``), parameters that are not JSON, or one the other process cannot build."""
    import json
    import logging
    import os
    import subprocess
    import sys

    cls = type(enc)
    module, qualname = getattr(cls, "__module__", ""), getattr(cls, "__qualname__", "")
    found = _varied_params(enc)
    if module in ("", "__main__") or "<locals>" in qualname or found is None:
        return
    if _rebuilt(enc) is None:  # the same parameters give another fingerprint
        return
    texts = ["chair", "table", "kitchen sink"]
    out = tmp_path / "other-process.npy"
    try:
        spec = json.dumps(
            {
                "module": module,
                "qualname": qualname,
                "params": found[0],
                "texts": texts,
                "out": str(out),
                "path": [p for p in sys.path if isinstance(p, str)],
            },
            default=_as_json,
        )
    except (TypeError, ValueError):
        return
    ours = np.asarray(enc.encode_text(texts), dtype=np.float32)
    seed = "2" if os.environ.get("PYTHONHASHSEED") == "1" else "1"
    try:
        done = subprocess.run(
            # the parameters on stdin, not the command line, which other users of the
            # machine can read (an encoder's API key is a parameter)
            [sys.executable, "-c", _OTHER_PROCESS],
            input=spec,
            env={**os.environ, "PYTHONHASHSEED": seed},
            capture_output=True,
            text=True,
            timeout=600,
        )
    except subprocess.TimeoutExpired:
        logging.getLogger(__name__).info(
            "%s: another process took over 600 s; not compared", qualname
        )
        return
    if done.returncode != 0 or not out.is_file():
        logging.getLogger(__name__).debug(
            "%s: not built in another process: %s", qualname, (done.stderr or "").strip()[-500:]
        )
        return
    theirs = np.load(out)
    assert theirs.shape == ours.shape and np.allclose(ours, theirs, atol=1e-5), (
        f"encode_text differs in another Python process: a {cls.__name__} built there with "
        "the same parameters (the same fingerprint) embedded the same texts differently"
        + (
            f" (by up to {float(np.abs(ours - theirs).max()):.3g})"
            if theirs.shape == ours.shape
            else ""
        )
        + f", with PYTHONHASHSEED={seed}. Python salts hash() of a string per process: draw "
        "a text's values from a stable digest (hashlib.blake2b, zlib.crc32) instead of "
        "hash(), and never from the order of a set of strings. The text cache and a map "
        "queried in another process than the one that built it rely on this."
    )


def _as_json(value: Any) -> Any:
    """A path as its string and a numpy scalar as its number, for the other process; any
    other value JSON lacks is refused (the check is then skipped)."""
    import os

    if isinstance(value, os.PathLike):
        return os.fspath(value)
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"not JSON: {type(value).__name__}")


def check_encoder_batch_independent(enc: Any, tmp_path: Path) -> None:
    pair = np.asarray(enc.encode_text(["chair", "table"]))
    single = _one_row(enc)  # a (dim,) row compared as a batch named the wrong fault
    assert np.allclose(pair[1], single[0], atol=1e-3), (
        "an embedding must not depend on its batch: 'table' embedded beside 'chair' differs "
        f"from 'table' alone by up to {float(np.abs(pair[1] - single[0]).max()):.3g}. Each "
        "text is cached on its own, so normalise per text (not over the batch) and mask "
        "any padding."
    )


def check_encoder_empty(enc: Any, tmp_path: Path) -> None:
    try:
        e = np.asarray(enc.encode_text([]))
    except Exception as exc:  # noqa: BLE001 - reported as the failure it is
        raise AssertionError(
            f"encode_text([]) raised {type(exc).__name__}: {str(exc).rstrip('.')}; it must "
            "return an empty (0, dim) float32 array, the contract's (n, dim) for n = 0: return "
            "np.zeros((0, self.dim), np.float32) for no texts"
        ) from exc
    assert e.shape == (0, enc.dim), f"encode_text([]) must be (0, dim); got {e.shape}"


def check_encoder_empty_string(enc: Any, tmp_path: Path) -> None:
    """The empty string ``""`` is embedded, as any other text is (one finite unit-norm
    row, the same alone and in a batch), or refused with an ``EncoderError`` (or a
    ``ValueError``) that says so. A query never sends it, but a label name or a line of
    a file read from Python can be ``""``; what fails is a NaN or zero row (a bag of no
    words divided by its norm), a dropped row, or an error that names nothing."""
    from ..core.errors import EncoderError

    try:
        alone = np.asarray(enc.encode_text([""]))
    except (EncoderError, ValueError) as exc:
        assert str(exc).strip(), (
            f"encode_text(['']) raised {type(exc).__name__} with no message: say that the "
            "empty string is refused"
        )
        return  # refused, with a message: the documented alternative to embedding it
    except Exception as exc:  # noqa: BLE001 - reported as the failure it is
        raise AssertionError(
            f"encode_text(['']) raised {type(exc).__name__}: {str(exc).rstrip('.')}; embed "
            "the empty string as any other text, or refuse it with "
            "quash_plugins.core.errors.EncoderError('... cannot embed the empty string') "
            "before the model sees it"
        ) from exc
    assert alone.shape == (1, enc.dim), (
        f"encode_text(['']) shape {alone.shape}, expected (1, {enc.dim}): one row per text, "
        "the empty one too (a dropped row shifts every row after it onto the wrong text); "
        "or refuse it with quash_plugins.core.errors.EncoderError"
    )
    norm = float(np.linalg.norm(alone.astype(np.float64)))
    assert np.isfinite(alone).all() and abs(norm - 1.0) <= 1e-3, (
        "encode_text(['']) returned "
        + ("NaN/Inf" if not np.isfinite(alone).all() else f"a row of norm {norm:.4g}")
        + ": the empty string has no words or tokens of its own, and a row of zeros "
        "divided by its norm is NaN. Give it a row (a boundary token, as "
        "`text.split() or ['']` does), or refuse it with "
        "quash_plugins.core.errors.EncoderError"
    )
    batch = np.asarray(enc.encode_text(["chair", ""]))
    assert batch.shape == (2, enc.dim) and np.allclose(batch[1], alone[0], atol=1e-3), (
        "encode_text(['chair', '']) must give the empty string the row it gets alone"
        + (
            f" (it differs by up to {float(np.abs(batch[1] - alone[0]).max()):.3g})"
            if batch.shape == (2, enc.dim)
            else f"; got shape {batch.shape}, expected (2, {enc.dim})"
        )
        + ": each text is embedded and cached on its own"
    )


def check_encoder_fingerprint(enc: Any, tmp_path: Path) -> None:
    fp = enc.fingerprint()
    assert isinstance(fp, str) and fp, "fingerprint() must be a non-empty string"
    assert fp == enc.fingerprint(), "fingerprint() must be stable"
    enc.encode_text(["chair"])
    assert fp == enc.fingerprint(), (
        "fingerprint() changed after encode_text: the default config() records public "
        "attributes, so keep state that changes with use (a loaded model, counters) in "
        "attributes whose names start with '_', or override config()"
    )
    assert isinstance(enc.name, str) and enc.name, "name must be a non-empty string"


#: Plugin -> the parameters the kit built it with (its ``conformance_params``): a
#: parameter without a default that the plugin keeps under another attribute name
#: (``self._path = vocab``) is known from here, not guessed.
_BUILT_WITH: weakref.WeakKeyDictionary[Any, dict[str, Any]] = weakref.WeakKeyDictionary()


def remember_params(plugin: Any, params: dict[str, Any]) -> None:
    """Record that the kit built ``plugin`` with ``params``."""
    import contextlib

    with contextlib.suppress(TypeError):  # not weakly referenceable (__slots__): not kept
        _BUILT_WITH[plugin] = dict(params)


def _varied_params(enc: Any) -> tuple[dict[str, Any], list[str]] | None:
    """The constructor's parameters with the values ``enc`` holds (as ``p`` or ``_p``,
    else the default), and the numeric, boolean, string, list and dict ones to vary;
    None when they cannot be known."""
    import inspect

    try:
        sig = inspect.signature(type(enc).__init__)
    except (TypeError, ValueError):
        return None
    try:
        built = _BUILT_WITH.get(enc, {})
    except TypeError:
        built = {}
    values: dict[str, Any] = {}
    for name, param in list(sig.parameters.items())[1:]:
        if param.kind not in (param.POSITIONAL_OR_KEYWORD, param.KEYWORD_ONLY):
            continue
        for attr in (name, "_" + name):
            if attr in vars(enc):
                values[name] = vars(enc)[attr]
                break
        else:
            if name in built:
                values[name] = built[name]
            elif param.default is param.empty:
                return None
            else:
                values[name] = param.default
    # numbers, switches (a `lowercase: True` changes the output as a size does), strings
    # (a prompt prefix, a salt, a mode), lists and dicts (prompt templates, weights)
    varied = [
        n
        for n, v in values.items()
        if n not in OUTPUT_NEUTRAL  # documented not to change the output: not varied
        and isinstance(v, (int, float, str, list, tuple, dict, np.integer, np.floating, np.bool_))
    ]
    return values, varied


def _other_values(enc: Any, name: str, old: Any) -> list[Any]:
    """Values to try for parameter ``name`` in place of ``old``: for a string, the other
    choices its annotation lists (``Literal["fast", "exact"]``), else what
    :func:`_nudged` gives (a value the class refuses is skipped)."""
    import typing

    from ..core.redact import is_secret_param

    if isinstance(old, str) and not is_secret_param(name):
        try:
            hint = typing.get_type_hints(type(enc).__init__).get(name)
        except Exception:  # noqa: BLE001 - an annotation that does not resolve: no choices
            hint = None
        # Literal["a", "b"], or one inside a union (Literal["a", "b"] | None)
        choices = [
            c
            for arg in (hint, *typing.get_args(hint))
            if typing.get_origin(arg) is typing.Literal
            for c in typing.get_args(arg)
        ]
        others = [c for c in choices if isinstance(c, str) and c != old]
        if others:
            return others[:4]
    return _nudged(name, old)[:4]


def _nudged(name: str, old: Any) -> list[Any]:
    """``old`` changed a little: the other switch, the next number, a string with a
    suffix; a list or tuple less its last item, and with its last item nudged; a dict
    with one value nudged (new containers: ``old`` is never changed in place).

    A credential (``api_key``, ``token``, or a dict key so named, whatever its type) is
    never varied, nor is a path or a URL, nor a list holding one: the kit would send a
    changed key to a server, or write a file beside the one named, and a model path
    changed (or a list of weight files shortened) is only a model that does not load."""
    from ..core.redact import is_secret_param

    if is_secret_param(name):  # before the numbers: a key may be one (api_key=12345)
        return []
    if isinstance(old, (bool, np.bool_)):
        return [not old]
    if isinstance(old, (int, np.integer)):
        return [old + 1]
    if isinstance(old, (float, np.floating)):
        return [old * 1.5 + 0.5]
    if isinstance(old, str):
        return [] if _path_like(old) else [f"{old}x"]
    if isinstance(old, dict):  # each value by its own key: a path or a key stays as it is
        return [{**old, k: v} for k, item in old.items() for v in _nudged(str(k), item)]
    if isinstance(old, (list, tuple)) and old and not _holds_path(old):
        items = list(old)
        others = [items[:-1]] if len(items) > 1 else []
        others += [[*items[:-1], v] for v in _nudged(name, items[-1])]
        return [tuple(o) if isinstance(old, tuple) else o for o in others]
    return []


def _holds_path(value: Any) -> bool:
    """True for a list, tuple or dict with a path or a URL (:func:`_path_like`) among its
    items, at any depth: shortened, a list of weight files names one file fewer."""
    if isinstance(value, str):
        return _path_like(value)
    if isinstance(value, dict):
        return any(_holds_path(v) for v in value.values())
    if isinstance(value, (list, tuple)):
        return any(_holds_path(v) for v in value)
    return False


def _path_like(text: str) -> bool:
    """True for a string that names a file, a folder or a URL."""
    if "/" in text or "\\" in text:
        return True
    try:
        return bool(text) and Path(text).exists()
    except (OSError, ValueError):  # a name too long, a NUL
        return False


def check_encoder_fingerprint_follows_params(enc: Any, tmp_path: Path) -> None:
    """A parameter that changes the output must change the fingerprint, or the text
    cache serves one setting's embeddings to the other (a stale cache)."""
    found = _varied_params(enc)
    if found is None:
        return
    values, varied = found
    texts = ["chair", "kitchen sink"]
    for name, old, new in (
        (n, values[n], v) for n in varied for v in _other_values(enc, n, values[n])
    ):
        try:
            a = type(enc)(**values)
            b = type(enc)(**{**values, name: new})
            if a.fingerprint() != b.fingerprint():
                continue
            ea = np.asarray(a.encode_text(texts), dtype=np.float64)
            eb = np.asarray(b.encode_text(texts), dtype=np.float64)
            again = np.asarray(a.encode_text(texts), dtype=np.float64)
        except Exception:  # noqa: BLE001 - a value it refuses, or weights it cannot load
            continue
        if not np.allclose(ea, again, atol=1e-5):
            return  # not deterministic: check_encoder_deterministic says so
        assert ea.shape == eb.shape and np.allclose(ea, eb, atol=1e-5), (
            f"parameter {name!r} changes the output ({name}={old!r} and {name}={new!r} "
            "embed the same texts differently) but not fingerprint(), which keys the "
            f"text-embedding cache: embeddings cached with {name}={old!r} would be served "
            f"to the encoder built with {name}={new!r}. Return {name!r} from config() "
            "(or keep it in a public attribute)."
        )


#: Every encoder check, in the order the kit runs them.
ENCODER_CHECKS = [
    check_encoder_output,
    check_encoder_deterministic,
    check_encoder_same_in_another_process,
    check_encoder_batch_independent,
    check_encoder_empty,
    check_encoder_empty_string,
    check_encoder_fingerprint,
    check_encoder_fingerprint_follows_params,
]
