"""Any scikit-learn estimator, by dotted path, as a QuASH classifier."""

from __future__ import annotations

import importlib
import keyword
from typing import Any

import numpy as np
from sklearn.base import clone

from ..core.interfaces import Classifier
from ._params import (
    ClassifierParamError,
    check_finite_rows,
    iter_blocks,
    map_rows,
    piecewise_display,
    training_set,
)


def _split_estimator_path(path: Any) -> tuple[str, str]:
    """``(module, class name)`` of ``module.path.Class`` or ``module.path:Class``.

    Only the shape is checked here (every part an identifier); nothing is imported.
    """
    who = "sklearn"
    example = "e.g. 'sklearn.neighbors.KNeighborsClassifier' or 'my_pkg.models:MyClassifier'"
    if not isinstance(path, str) or not path.strip():
        raise ClassifierParamError(
            f"{who}: parameter 'estimator' must be a dotted path to a class, {example}; "
            f"got {path!r}."
        )
    text = path.strip()
    if text.count(":") > 1:
        raise ClassifierParamError(f"{who}: estimator {path!r} has more than one ':'; {example}.")
    module, sep, name = text.partition(":")
    if not sep:
        module, _, name = text.rpartition(".")
    parts = module.split(".") if module else []
    bad = [p for p in [*parts, name] if not p.isidentifier() or keyword.iskeyword(p)]
    if not parts or bad:
        raise ClassifierParamError(
            f"{who}: estimator {path!r} must be a dotted path to a class, module.path.Class "
            f"or module.path:Class ({'bad part ' + repr(bad[0]) if bad else 'no module'}); "
            f"{example}."
        )
    return module, name


def _binds(module: str, name: str) -> str | None:
    """How ``module``'s source binds ``name`` at top level, read without importing it.

    ``"class"`` (a class statement), ``"function"`` (a def), ``"name"`` (an import or an
    assignment), ``"absent"``; None when the source cannot tell (no Python source, a
    module ``__getattr__`` or a star import). Finding the module imports its parent
    packages (for ``sklearn.neighbors``: ``sklearn``), never the module itself.
    """
    import ast
    import importlib.util

    try:
        spec = importlib.util.find_spec(module)
    except (ImportError, ValueError) as exc:
        raise ClassifierParamError(
            f"sklearn: cannot find the module of estimator {module}.{name} "
            f"({type(exc).__name__}: {exc})."
        ) from None
    if spec is None:
        raise ClassifierParamError(
            f"sklearn: no module {module!r} is installed (estimator {module}.{name})."
        )
    origin = spec.origin or ""
    if not origin.endswith(".py"):
        return None
    try:
        with open(origin, encoding="utf-8") as f:
            tree = ast.parse(f.read(), filename=origin)
    except (OSError, SyntaxError, UnicodeDecodeError, ValueError):
        return None
    found = "absent"
    for node in _module_level(tree.body):
        if isinstance(node, ast.FunctionDef) and node.name == "__getattr__":
            return None
        if isinstance(node, ast.ClassDef) and node.name == name:
            found = "class"
        elif isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) and node.name == name:
            found = "function"
        elif isinstance(node, ast.Import | ast.ImportFrom):
            for alias in node.names:
                if alias.name == "*":
                    return None
                if (alias.asname or alias.name.split(".")[0]) == name:
                    found = "name"
        elif isinstance(node, ast.Assign | ast.AnnAssign):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            if any(isinstance(t, ast.Name) and t.id == name for t in targets):
                found = "name"
    return found


def _module_level(body: list[Any]) -> Any:
    """The statements run at module level: into if/try/with blocks, not into defs."""
    import ast

    for node in body:
        yield node
        if isinstance(node, ast.If | ast.For | ast.While | ast.With | ast.Try):
            for field in ("body", "orelse", "finalbody"):
                yield from _module_level(getattr(node, field, []))
            for handler in getattr(node, "handlers", []):
                yield from _module_level(handler.body)


def _import_estimator(path: Any) -> type:
    """The estimator class named by ``path``, checked before its module is imported.

    A config can name any installed module here, and importing a module runs its
    top-level code. So the name's shape is checked first, then the module's source is
    read (without importing it) to see that it binds the class name; only then is it
    imported. See docs/security.md.
    """
    who = "sklearn"
    module, name = _split_estimator_path(path)
    binding = _binds(module, name)
    if binding == "absent":
        raise ClassifierParamError(
            f"{who}: module {module!r} defines no {name!r} (estimator {path!r}); it was not "
            "imported. Check the spelling, e.g. 'sklearn.neighbors.KNeighborsClassifier'."
        )
    if binding == "function":
        raise ClassifierParamError(
            f"{who}: {path!r} is a function, not a class; it was not imported. Name an "
            "estimator class, e.g. 'sklearn.neighbors.KNeighborsClassifier'."
        )
    try:
        obj = getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError) as exc:
        raise ClassifierParamError(
            f"{who}: cannot import estimator {path!r} ({type(exc).__name__}: {exc})."
        ) from exc
    if not isinstance(obj, type):
        raise ClassifierParamError(f"{who}: {path!r} is not a class.")
    missing = [m for m in ("fit", "get_params") if not hasattr(obj, m)]
    if missing:
        raise ClassifierParamError(
            f"{who}: {path!r} is not a scikit-learn estimator (it lacks {', '.join(missing)})."
        )
    if not (hasattr(obj, "decision_function") or hasattr(obj, "predict_proba")):
        raise ClassifierParamError(
            f"{who}: {path!r} has neither decision_function nor predict_proba, so it "
            "cannot score map items. Pick a classifier that has one of them."
        )
    return obj


class SklearnClassifier(Classifier):
    """Wraps any scikit-learn classifier named by its dotted path.

    ``decision_function`` is the estimator's own ``decision_function`` (sign arranged
    so that > 0 means the positive class), or ``predict_proba[:, positive] - 0.5`` when
    it has none. Map rows are passed in blocks of ``block_rows``.

    Parameters
    ----------
    estimator
        Dotted path, e.g. ``"sklearn.neighbors.KNeighborsClassifier"``.
    params
        Keyword arguments for the estimator; unknown ones are rejected.
    block_rows
        Rows per call into the estimator (bounds its memory).
    """

    def __init__(
        self,
        estimator: str = "sklearn.linear_model.LogisticRegression",
        params: dict[str, Any] | None = None,
        block_rows: int = 65536,
    ) -> None:
        self.estimator = estimator
        self.params = params
        self.block_rows = block_rows

    def check_params(self) -> None:
        """Import the estimator and check ``params`` and ``block_rows`` without fitting."""
        self._build()

    def _build(self) -> Any:
        cls = _import_estimator(self.estimator)
        params = self.params or {}
        if not isinstance(params, dict):
            raise ClassifierParamError(f"sklearn: 'params' must be a mapping; got {params!r}.")
        try:
            est = cls()
            known = est.get_params(deep=False)
            unknown = [k for k in params if k not in known]
            if unknown:
                raise ClassifierParamError(
                    f"sklearn: {self.estimator} does not accept parameter {unknown[0]!r}. "
                    f"Accepted: {', '.join(sorted(known))}."
                )
            est.set_params(**params)
        except (TypeError, ValueError) as exc:
            if isinstance(exc, ClassifierParamError):
                raise
            raise ClassifierParamError(f"sklearn: cannot build {self.estimator}: {exc}") from exc
        if not isinstance(self.block_rows, int) or self.block_rows < 1:
            raise ClassifierParamError("sklearn: 'block_rows' must be a positive integer.")
        return est

    def fit(self, X: np.ndarray, y: np.ndarray) -> SklearnClassifier:
        est = self._build()
        X, y = training_set(self, "sklearn", X, y)
        self.estimator_ = clone(est).fit(X, y)
        self.positive_index_ = int(np.flatnonzero(np.asarray(self.estimator_.classes_) == 1)[0])
        self.uses_proba_ = not hasattr(self.estimator_, "decision_function")
        return self

    def _block_scores(self, block: np.ndarray) -> np.ndarray:
        est = self.estimator_
        pos = self.positive_index_
        if self.uses_proba_:
            return est.predict_proba(block)[:, pos] - 0.5
        d = np.asarray(est.decision_function(block))
        if d.ndim == 2:
            d = d[:, pos]
        elif pos == 0:
            d = -d
        return d

    def decision_function(self, E: Any) -> np.ndarray:
        """``(N,)`` float32 scores, > 0 for the positive class; ``E`` is read in blocks."""
        E = map_rows(self, "sklearn", E)
        out = np.empty(len(E), dtype=np.float32)
        for start, stop, block in iter_blocks(E, self.block_rows):
            check_finite_rows("sklearn", block, offset=start)
            out[start:stop] = self._block_scores(block)
        return out

    def display_scores(self, scores: np.ndarray, threshold: float = 0.0) -> np.ndarray:
        """``predict_proba`` when that is what scores are (cut 0.5 + threshold), else logistic."""
        if getattr(self, "uses_proba_", False):
            return piecewise_display(np.asarray(scores) + 0.5, 0.5 + threshold)
        return super().display_scores(scores, threshold)
