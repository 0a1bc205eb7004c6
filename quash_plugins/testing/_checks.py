"""The individual conformance checks."""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..core import registry
from ..core.errors import ConfigError, QuashError, closest
from ..core.interfaces import Encoder, ExpansionContext
from ..core.types import LatentMap, QuerySet

_WORDS = [
    "chair",
    "table",
    "sofa",
    "bed",
    "lamp",
    "window",
    "door",
    "floor",
    "wall",
    "sink",
    "armchair",
    "stool",
    "bench",
    "desk",
    "shelf",
    "plant",
    "other",
    "background",
]


class HashingEncoder(Encoder):
    """Deterministic test encoder: each string maps to a fixed random unit vector.

    Strings sharing words share components, so related phrases are closer than
    unrelated ones. Used by the kit to exercise heuristics without a real model.
    """

    name = "hashing-test"

    def __init__(self, dim: int = 32) -> None:
        self._dim = int(dim)

    @property
    def dim(self) -> int:
        return self._dim

    def _word(self, word: str) -> np.ndarray:
        seed = int.from_bytes(hashlib.sha256(word.encode()).digest()[:8], "little")
        return np.random.default_rng(seed).normal(size=self._dim)

    def encode_text(self, texts):
        out = np.zeros((len(texts), self._dim), dtype=np.float64)
        for i, t in enumerate(texts):
            for w in str(t).lower().split() or [""]:
                out[i] += self._word(w)
        out /= np.linalg.norm(out, axis=1, keepdims=True)
        return out.astype(np.float32)

    def config(self):
        return {"dim": self._dim}


@dataclass
class PluginCheck:
    """One check bound to one plugin; call it with a temporary directory."""

    kind: str
    name: str
    check: Callable[[Any, Path], None]

    @property
    def id(self) -> str:
        return f"{self.kind}:{self.name}-{self.check.__name__}"

    def __call__(self, tmp_path: Path) -> None:
        import pytest

        cls = registry.load(self.kind, self.name)
        reason = getattr(cls, "conformance_skip", None)
        if reason:
            pytest.skip(f"{self.kind}:{self.name}: {reason}")
        tmp_path = Path(tmp_path)
        tmp_path.mkdir(parents=True, exist_ok=True)
        plugin = build(self.kind, self.name, tmp_path)
        try:
            self.check(plugin, tmp_path)
        except AssertionError as exc:
            # run outside pytest's ids (check_plugin), a failure names whose check it is
            raise AssertionError(f"{self.id}: {exc}") from exc
        except Exception as exc:  # noqa: BLE001 - the plugin's own error: a failure too
            raise AssertionError(f"{self.id}: {_raised(exc)}") from exc


def _raised(exc: BaseException) -> str:
    """A check's failure when the plugin raised rather than returned something wrong."""
    return (
        f"the plugin raised {type(exc).__name__}: {str(exc).rstrip('.')}. The check calls "
        "it as a query does (see the traceback above for where it raised)."
    )


def build(kind: str, name: str, tmp_path: Path) -> Any:
    """Build a plugin with its ``conformance_params`` (if any).

    A plugin without them that cannot be built with no arguments fails with what to
    add: the kit cannot guess a file or a URL.
    """
    import inspect

    cls = registry.load(kind, name)
    params = {}
    factory = getattr(cls, "conformance_params", None)
    if inspect.isclass(cls) and inspect.isfunction(
        inspect.getattr_static(cls, "conformance_params", None)
    ):
        # a plain method: called on the class, tmp_path would be taken for self
        raise ConfigError(
            f"{cls.__qualname__}.conformance_params ({kind[:-1]} {name!r}) is a plain "
            "method; the conformance kit calls it on the class: decorate it with "
            "@classmethod (def conformance_params(cls, tmp_path) -> dict)."
        )
    if callable(factory):
        params = dict(factory(Path(tmp_path)))
    try:
        return registry.create(kind, name, **params)
    except ConfigError as exc:
        if callable(factory):
            given = ", ".join(params) or "no parameters"
            raise ConfigError(
                f"{exc} The conformance kit built it with what "
                f"{getattr(cls, '__qualname__', name)}.conformance_params(tmp_path) returns "
                f"({given}): fix that."
            ) from exc
        raise ConfigError(
            f"{exc} The conformance kit builds {kind[:-1]} {name!r} with no arguments: "
            "give its class a classmethod conformance_params(tmp_path) -> dict with the "
            "arguments to build it with (files may be written under tmp_path), or set "
            "conformance_skip = 'why' on it."
        ) from exc


# ---------------------------------------------------------------- encoders
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


#: Parameters documented not to change the output (docs/plugins.md): not varied.
_OUTPUT_NEUTRAL = ("device", "batch_size")


def _varied_params(enc: Any) -> tuple[dict[str, Any], list[str]] | None:
    """The constructor's parameters with the values ``enc`` holds (as ``p`` or ``_p``,
    else the default), and the numeric, boolean and string ones to vary; None when
    they cannot be known."""
    import inspect

    try:
        sig = inspect.signature(type(enc).__init__)
    except (TypeError, ValueError):
        return None
    values: dict[str, Any] = {}
    for name, param in list(sig.parameters.items())[1:]:
        if param.kind not in (param.POSITIONAL_OR_KEYWORD, param.KEYWORD_ONLY):
            continue
        for attr in (name, "_" + name):
            if attr in vars(enc):
                values[name] = vars(enc)[attr]
                break
        else:
            if param.default is param.empty:
                return None
            values[name] = param.default
    # numbers, switches (a `lowercase: True` changes the output as a size does) and
    # strings (a prompt prefix, a salt, a mode)
    varied = [
        n
        for n, v in values.items()
        if n not in _OUTPUT_NEUTRAL
        and isinstance(v, (int, float, str, np.integer, np.floating, np.bool_))
    ]
    return values, varied


def _other_values(enc: Any, name: str, old: Any) -> list[Any]:
    """Values to try for parameter ``name`` in place of ``old``: the other switch, the
    next number, and for a string the other choices its annotation lists
    (``Literal["fast", "exact"]``), else ``old`` with a suffix (a value the class
    refuses, a path that is not there, is skipped)."""
    import typing

    if isinstance(old, (bool, np.bool_)):
        return [not old]
    if isinstance(old, (int, np.integer)):
        return [old + 1]
    if not isinstance(old, str):
        return [old * 1.5 + 0.5]
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
    return others[:4] if others else [f"{old}x"]


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


# ---------------------------------------------------------------- heuristics
def _context(seed: int = 0) -> ExpansionContext:
    return ExpansionContext(
        encoder=HashingEncoder(), label_names=["chair", "table", "sofa"], seed=seed
    )


def check_heuristic_queryset(h: Any, tmp_path: Path) -> None:
    qs = h.expand("chair", _context())
    assert isinstance(qs, QuerySet), f"expand must return a QuerySet; got {type(qs).__name__}"
    assert qs.positives, "a query set needs at least one positive"
    assert all(isinstance(p, str) and p for p in [*qs.positives, *qs.negatives])
    assert not set(qs.positives) & set(qs.negatives), "a string cannot be positive and negative"
    assert isinstance(qs.provenance, dict) and qs.provenance.get("heuristic"), (
        "provenance must record the heuristic"
    )
    QuerySet.from_dict(qs.to_dict())


def check_heuristic_seeded(h: Any, tmp_path: Path) -> None:
    a = h.expand("chair", _context(seed=7)).to_dict()
    b = h.expand("chair", _context(seed=7)).to_dict()
    assert a == b, (
        "the same seed must give the same query set: draw randomness from "
        "context.seed (np.random.default_rng(context.seed)) or from the query text, "
        "never from the global random state"
    )


# ---------------------------------------------------------------- classifiers
def _toy(rng: np.random.Generator, d: int = 32) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    centre_p, centre_n = rng.normal(size=d), rng.normal(size=d)
    X = np.concatenate(
        [centre_p + 0.3 * rng.normal(size=(12, d)), centre_n + 0.3 * rng.normal(size=(20, d))]
    )
    X /= np.linalg.norm(X, axis=1, keepdims=True)
    y = np.array([1] * 12 + [0] * 20)
    E = np.concatenate(
        [centre_p + 0.3 * rng.normal(size=(50, d)), centre_n + 0.3 * rng.normal(size=(50, d))]
    )
    E /= np.linalg.norm(E, axis=1, keepdims=True)
    return X.astype(np.float32), y, E.astype(np.float32)


def expected_failed_checks(clf: Any) -> dict[str, str]:
    """The scikit-learn checks ``clf`` declares it fails by design: ``{check: reason}``.

    A classifier declares them with a method ``expected_failed_checks(self)`` returning
    that mapping (the form scikit-learn's ``check_estimator`` takes), one reason per
    check; none by default.
    """
    declared = getattr(clf, "expected_failed_checks", None)
    out = dict(declared()) if callable(declared) else {}
    for check, reason in out.items():
        assert isinstance(reason, str) and reason.strip(), (
            f"{type(clf).__name__}.expected_failed_checks(): {check!r} needs a reason"
        )
    return out


def check_classifier_sklearn_estimator(clf: Any, tmp_path: Path) -> None:
    """scikit-learn's own ``check_estimator``: every check passes or is declared.

    A declared expected failure that passes is reported too (the declaration is stale),
    as is one naming a check that scikit-learn does not run on this classifier.
    """
    import warnings

    from sklearn.utils.estimator_checks import check_estimator

    expected = expected_failed_checks(clf)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        results = check_estimator(clf, on_fail=None, on_skip=None, expected_failed_checks=expected)
    failed = [
        f"{r['check_name']}: {type(r['exception']).__name__}: "
        f"{str(r['exception']).strip().splitlines()[0] if str(r['exception']).strip() else ''}"
        for r in results
        if r["status"] == "failed"
    ]
    ran = {r["check_name"] for r in results}
    xfailed = {r["check_name"] for r in results if r["status"] == "xfail"}
    stale = sorted(set(expected) - xfailed)
    problems = []
    if failed:
        problems.append("failed scikit-learn checks:\n  " + "\n  ".join(failed))
    if stale:
        problems.append(
            "declared in expected_failed_checks() but "
            + ", ".join(f"{c} ({'passes' if c in ran else 'not run'})" for c in stale)
        )
    assert not problems, f"{type(clf).__name__}: " + "\n".join(problems)


def check_classifier_params(clf: Any, tmp_path: Path) -> None:
    from sklearn.base import clone

    params = clf.get_params(deep=False)
    twin = clone(clf)
    assert twin.get_params(deep=False).keys() == params.keys(), "clone must keep the parameters"
    clf.set_params(**params)


def check_classifier_fit_predict(clf: Any, tmp_path: Path) -> None:
    from sklearn.base import clone

    X, y, E = _toy(np.random.default_rng(0))
    X0, E0 = X.copy(), E.copy()
    fitted = clone(clf).fit(X, y)
    assert fitted is not None, "fit must return self"
    np.testing.assert_array_equal(X, X0, err_msg="fit must not modify X")
    s = np.asarray(fitted.decision_function(E))
    np.testing.assert_array_equal(E, E0, err_msg="decision_function must not modify E")
    assert s.shape == (len(E),), f"decision_function shape {s.shape}, expected ({len(E)},)"
    assert np.isfinite(s).all(), "decision_function returned NaN/Inf"
    s = np.asarray(fitted.postprocess_scores(s)) if hasattr(fitted, "postprocess_scores") else s
    assert s[:50].mean() > s[50:].mean(), "items near the positives must score higher"
    pred = np.asarray(fitted.predict(E))
    assert pred.shape == (len(E),)


def check_classifier_chunk_invariant(clf: Any, tmp_path: Path) -> None:
    from sklearn.base import clone

    X, y, E = _toy(np.random.default_rng(1))
    fitted = clone(clf).fit(X, y)
    whole = np.asarray(fitted.decision_function(E), dtype=np.float64)
    parts = np.concatenate(
        [
            np.asarray(fitted.decision_function(E[i : i + 17]), dtype=np.float64)
            for i in range(0, len(E), 17)
        ]
    )
    np.testing.assert_allclose(
        whole, parts, atol=1e-4, err_msg="decision_function must not depend on the chunking"
    )


def check_classifier_expansions(clf: Any, tmp_path: Path) -> None:
    """A classifier that implements ``StackableClassifier`` or ``CosineClassifier`` is
    scored by the engine from its expansion, not by ``decision_function``: the two must
    agree (and a declared ``CosineMargin`` must be the same reduction)."""
    from sklearn.base import clone

    from ..core.kernels import KernelStack

    X, y, E = _toy(np.random.default_rng(2))
    E = E * np.random.default_rng(3).uniform(0.5, 2.0, (len(E), 1)).astype(np.float32)
    E[:3] = 0.0  # zero rows: cosine 0 (the pipeline masks them anyway)
    fitted = clone(clf).fit(X, y)
    own = np.asarray(fitted.decision_function(E), dtype=np.float64)
    observed = np.linalg.norm(E, axis=1) > 0
    kernel = getattr(fitted, "kernel_expansion", None)
    exp = kernel() if callable(kernel) else None
    if exp is not None:
        got = KernelStack([exp.part]).evaluate(E, unit=exp.unit_rows)[:, 0]
        np.testing.assert_allclose(
            got[observed],
            own[observed],
            atol=1e-4,
            err_msg="kernel_expansion() must give what decision_function gives",
        )
    cosine = getattr(fitted, "cosine_expansion", None)
    cexp = cosine() if callable(cosine) else None
    if cexp is None:
        return
    n = np.linalg.norm(E, axis=1, keepdims=True)
    U = np.divide(E, n, out=np.zeros_like(E), where=n > 0)
    c = (U @ np.asarray(cexp.labels, np.float32).T).astype(np.float32)
    got = np.asarray(cexp.reduce(c), dtype=np.float64)
    np.testing.assert_allclose(
        got[observed],
        own[observed],
        atol=1e-4,
        err_msg="cosine_expansion().reduce of the cosines must give what decision_function gives",
    )
    if cexp.margin is not None:
        np.testing.assert_allclose(
            cexp.margin.apply(c),
            got,
            atol=1e-5,
            err_msg="cosine_expansion().margin must be the same reduction as reduce",
        )


# ---------------------------------------------------------------- adapters
def _digest(source: Any) -> str | None:
    if not isinstance(source, (str, Path)):
        return None
    p = Path(source)
    h = hashlib.sha256()
    files = sorted(p.rglob("*")) if p.is_dir() else [p]
    for f in files:
        if f.is_file():
            h.update(str(f.relative_to(p if p.is_dir() else p.parent)).encode())
            h.update(f.read_bytes())
    return h.hexdigest()


def check_adapter_roundtrip(adapter: Any, tmp_path: Path) -> None:
    try:
        source = adapter.write_example(tmp_path / "example")
    except NotImplementedError:
        import pytest

        pytest.skip(f"adapter {adapter.name!r} provides no write_example()")
    before = _digest(source)
    assert adapter.sniff(source) is True, "sniff must accept the adapter's own example"
    lmap = adapter.read(source)
    assert isinstance(lmap, LatentMap), f"read must return a LatentMap; got {type(lmap).__name__}"
    assert lmap.n > 0 and lmap.dim > 0
    block = np.asarray(lmap.embeddings[: min(lmap.n, 8)])
    assert block.shape == (min(lmap.n, 8), lmap.dim)
    assert _digest(source) == before, "read must not modify the source"


def check_adapter_sniff_rejects(adapter: Any, tmp_path: Path) -> None:
    junk = tmp_path / "junk.bin"
    junk.write_bytes(b"\x00not a map\x00" * 10)
    for source in (junk, tmp_path / "missing.file", object(), 42):
        try:
            ok = adapter.sniff(source)
        except Exception as exc:  # noqa: BLE001
            raise AssertionError(
                f"sniff must never raise; got {type(exc).__name__}: {exc}"
            ) from exc
        assert ok is False, f"sniff must reject {source!r}"


def check_adapter_bad_input(adapter: Any, tmp_path: Path) -> None:
    junk = tmp_path / "junk.bin"
    junk.write_bytes(b"\x00not a map\x00" * 10)
    try:
        adapter.read(junk)
    except QuashError:
        return
    except Exception as exc:  # noqa: BLE001
        raise AssertionError(
            f"read of a malformed file must raise a QuashError; got {type(exc).__name__}: {exc}"
        ) from exc
    raise AssertionError("read of a malformed file must raise a QuashError")


_CHECKS: dict[str, list[Callable[[Any, Path], None]]] = {
    "encoders": [
        check_encoder_output,
        check_encoder_deterministic,
        check_encoder_same_in_another_process,
        check_encoder_batch_independent,
        check_encoder_empty,
        check_encoder_empty_string,
        check_encoder_fingerprint,
        check_encoder_fingerprint_follows_params,
    ],
    "heuristics": [check_heuristic_queryset, check_heuristic_seeded],
    "classifiers": [
        check_classifier_params,
        check_classifier_fit_predict,
        check_classifier_chunk_invariant,
        check_classifier_expansions,
        check_classifier_sklearn_estimator,
    ],
    "adapters": [check_adapter_roundtrip, check_adapter_sniff_rejects, check_adapter_bad_input],
}


def _selected(kinds: str | list[str] | None) -> list[str]:
    """The plugin kinds a selection names (one, several, or None: every kind)."""
    if isinstance(kinds, str):
        kinds = [kinds]
    return [registry.normalize_kind(k) for k in kinds] if kinds else list(registry.KINDS)


def plugin_checks(
    kinds: str | list[str] | None = None, names: list[str] | None = None, dist: str | None = None
) -> list[PluginCheck]:
    """Every (plugin, check) pair for the selected kinds, names and distribution."""
    selected = _selected(kinds)
    out = []
    for kind in selected:
        for info in registry.plugins(kind):
            if names is not None and info.name not in names:
                continue
            if dist is not None and not registry._same_dist(info.dist, dist):
                continue
            qualified = info.qualified if _ambiguous(kind, info.name) else info.name
            try:
                registry.load(kind, qualified)
            except QuashError:
                # one failing check says why it does not load, not one per check
                out.append(PluginCheck(kind, qualified, check_plugin_loads))
                continue
            out.extend(PluginCheck(kind, qualified, c) for c in _CHECKS[kind])
    return out


def misplaced_hint(
    kinds: str | list[str] | None = None, names: list[str] | None = None, dist: str | None = None
) -> str:
    """For a selection that matched no plugin: the entry points it would match that sit
    in a group quash-plugins does not read (``quash_plugins.encoder``...) or in another
    kind's group (an encoder under ``quash_plugins.heuristics``), each with the group to
    move it to; else an empty string. Either mistake is otherwise reported as a plugin
    that is not installed."""
    selected = _selected(kinds)
    groups = {registry.GROUP_PREFIX + k for k in selected}
    found = [
        m.message()
        for m in registry.misplaced_entry_points()
        if (m.meant is None or m.meant in groups)
        and (names is None or m.name in names)
        and (dist is None or registry._same_dist(m.dist, dist))
    ]
    if names is None and dist is None:
        return " ".join(found)
    # registered, but as another kind (an encoder in quash_plugins.heuristics)
    wanted = " or ".join(k[:-1] for k in selected)
    found += [
        f"Distribution {i.dist!r} registers {i.name!r} ({i.target}) as a {i.kind[:-1]}, "
        f"in group {registry.GROUP_PREFIX + i.kind!r}: if it is meant as {wanted}, move "
        f"it to {' or '.join(repr(registry.GROUP_PREFIX + k) for k in selected)}."
        for i in registry.plugins()
        if i.kind not in selected
        and (names is None or i.name in names)
        and (dist is None or registry._same_dist(i.dist, dist))
    ]
    return " ".join(found)


def near_hint(
    kinds: str | list[str] | None = None, names: list[str] | None = None, dist: str | None = None
) -> str:
    """For a selection that matched no plugin: the registered distribution and plugin
    names nearest to those asked for (``dist="my-quash-plugn"`` -> ``Did you mean
    'my-quash-plugin'?``); else an empty string."""
    selected = _selected(kinds)
    infos = [i for i in registry.plugins() if i.kind in selected]
    dists = sorted({i.dist for i in infos})
    guesses = []
    if dist is not None and not any(registry._same_dist(d, dist) for d in dists):
        guess = closest(dist, dists)
        guesses += [f"dist {guess!r}"] if guess else []
    known = sorted({i.name for i in infos})
    for name in names or ():
        guess = closest(name, known) if name not in known else None
        guesses += [f"{guess!r} for {name!r}"] if guess else []
    return f"Did you mean {' and '.join(guesses)}?" if guesses else ""


def check_plugin_loads(plugin: Any, tmp_path: Path) -> None:
    """Stands for every check of a plugin that does not load: :class:`PluginCheck`
    loads the plugin first, so running it raises the load error (what to fix)."""


def _ambiguous(kind: str, name: str) -> bool:
    return len({i.dist for i in registry.plugins(kind) if i.name == name}) > 1


def check_plugin(kind: str, name: str, tmp_path: str | Path) -> None:
    """Run every check for one plugin; raise AssertionError on the first failure.

    ``name`` is a plugin name, or ``dist:name`` for one distribution's plugin when
    several register the name (only that one is checked). A name no plugin has is an
    error: a check that ran nothing would pass.
    """
    dist, _, short = name.rpartition(":")
    checks = plugin_checks(kinds=kind, names=[short], dist=dist or None)
    if not checks:
        hint = misplaced_hint(kind, [short], dist or None) or near_hint(kind, [short], dist or None)
        plugin = f"No {registry.normalize_kind(kind)[:-1]} plugin named {name!r}"
        raise ConfigError(
            f"{plugin} is registered. {hint}"
            if hint
            else f"{plugin} is installed; `quash plugins` lists them."
        )
    for c in checks:
        c(Path(tmp_path) / c.check.__name__)


def _run_all(kind: str, plugin: Any, tmp_path: str | Path | None) -> None:
    if tmp_path is None:
        import tempfile

        # a folder of the kit's own, removed afterwards (one was left behind per call)
        with tempfile.TemporaryDirectory(prefix="quash-kit-", ignore_cleanup_errors=True) as tmp:
            return _run_all(kind, plugin, tmp)
    base = Path(tmp_path)
    who = getattr(plugin, "name", None) or type(plugin).__name__
    # what the registry refuses a plugin for, said as it says it (not as an AttributeError
    # of the first check that calls the missing method)
    missing = [a for a in registry._BASES[kind] if not hasattr(plugin, a)]
    if missing:
        raise AssertionError(
            f"{kind[:-1]} {who!r} breaks the {kind[:-1]} interface: it lacks "
            f"{', '.join(missing)}. Subclass quash_plugins.{registry._base_of(kind).__name__}."
        )
    for c in _CHECKS[kind]:
        d = base / c.__name__
        d.mkdir(parents=True, exist_ok=True)
        try:
            c(plugin, d)
        except AssertionError as exc:
            raise AssertionError(f"{kind[:-1]} {who!r}: {c.__name__}: {exc}") from exc
        except Exception as exc:  # noqa: BLE001 - the plugin's own error: a failure too
            raise AssertionError(f"{kind[:-1]} {who!r}: {c.__name__}: {_raised(exc)}") from exc


def check_encoder(encoder: Any, tmp_path: str | Path | None = None) -> None:
    """Run every encoder check on an instance."""
    _run_all("encoders", encoder, tmp_path)


def check_heuristic(heuristic: Any, tmp_path: str | Path | None = None) -> None:
    """Run every heuristic check on an instance."""
    _run_all("heuristics", heuristic, tmp_path)


def check_classifier(classifier: Any, tmp_path: str | Path | None = None) -> None:
    """Run every classifier check on an (unfitted) instance."""
    _run_all("classifiers", classifier, tmp_path)


def check_adapter(adapter: Any, tmp_path: str | Path | None = None) -> None:
    """Run every adapter check on an instance."""
    _run_all("adapters", adapter, tmp_path)
