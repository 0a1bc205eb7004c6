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

# the encoder checks, in a module of their own; importable from here as before
from ._encoder_checks import (  # noqa: F401 - re-exported
    ENCODER_CHECKS,
    check_encoder_batch_independent,
    check_encoder_deterministic,
    check_encoder_empty,
    check_encoder_empty_string,
    check_encoder_fingerprint,
    check_encoder_fingerprint_follows_params,
    check_encoder_output,
    check_encoder_same_in_another_process,
    remember_params,
)

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
        plugin = registry.create(kind, name, **params)
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
    remember_params(plugin, params)
    return plugin


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
    "encoders": ENCODER_CHECKS,
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
