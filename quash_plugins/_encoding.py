"""Turning a :class:`QuerySet` into a training set: text encoding, caching, templates."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from importlib import resources
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from .errors import ConfigError
from .interfaces import Encoder, check_text_embeddings
from .types import QuerySet

log = logging.getLogger(__name__)

TEMPLATE_MODES = ("mean", "all")

#: A negative spelled like this is the zero vector, not a word (the paper's ablation).
ZERO_TOKEN = "<zero>"


class TextCache(Protocol):
    """What the pipeline needs from a text-embedding cache."""

    def lookup(self, fingerprint: str, texts: Sequence[str]) -> dict[str, np.ndarray]: ...

    def store(self, fingerprint: str, embeddings: dict[str, np.ndarray]) -> None: ...


def encode_texts(
    encoder: Encoder, texts: Sequence[str], cache: TextCache | None = None
) -> np.ndarray:
    """Embed ``texts`` with ``encoder``, serving what it can from ``cache``.

    Returns ``(len(texts), encoder.dim)`` float32, unit-norm rows. Only strings missing
    from the cache reach the model, each once.
    """
    texts = list(texts)
    dim = int(encoder.dim)
    if not texts:
        return np.zeros((0, dim), dtype=np.float32)
    found: dict[str, np.ndarray] = {}
    fp = None
    if cache is not None:
        fp = encoder.fingerprint()
        found = cache.lookup(fp, texts)
    missing = list(dict.fromkeys(t for t in texts if t not in found))
    if missing:
        log.debug("encoding %d new strings with %s", len(missing), encoder.name)
        emb = check_text_embeddings(encoder.encode_text(missing), missing, dim, encoder.name)
        new = dict(zip(missing, emb))
        found.update(new)
        if cache is not None and fp is not None:
            cache.store(fp, new)
    return np.stack([found[t] for t in texts]).astype(np.float32, copy=False)


def load_templates(spec: Any) -> list[str]:
    """Resolve a ``templates`` setting: ``"default"``, a list, or a text/YAML file path."""
    if spec is None or spec == "default":
        text = (
            resources.files("quash_plugins.data")
            .joinpath("prompt_templates.txt")
            .read_text(encoding="utf-8")
        )
        templates = [ln.strip() for ln in text.splitlines()]
    elif isinstance(spec, (list, tuple)):
        templates = [str(t) for t in spec]
    else:
        path = Path(str(spec))
        if not path.exists():
            raise ConfigError(f"Prompt-template file not found: {path}")
        if path.suffix in (".yaml", ".yml"):
            import yaml

            data = yaml.safe_load(path.read_text(encoding="utf-8"))
            if not isinstance(data, list):
                raise ConfigError(f"{path}: expected a YAML list of templates with '{{}}'.")
            templates = [str(t) for t in data]
        else:
            templates = [ln.strip() for ln in path.read_text(encoding="utf-8").splitlines()]
    templates = [t for t in templates if t and not t.startswith("#")]
    bad = [t for t in templates if t.count("{}") != 1]
    if bad:
        raise ConfigError(f"Prompt template {bad[0]!r} must contain exactly one '{{}}'.")
    if not templates:
        raise ConfigError("The prompt-template list is empty.")
    return templates


def training_set(
    encoder: Encoder,
    queryset: QuerySet,
    cache: TextCache | None = None,
    templates: Sequence[str] | None = None,
    mode: str = "mean",
) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Encode a query set into ``X (n, D)`` float32, ``y (n,)`` int and the row texts.

    Positives come first (the query itself first of all), then negatives. With
    ``templates``, ``mode="mean"`` replaces each string by the normalised mean of its
    templated embeddings, and ``mode="all"`` makes every templated variant a sample.
    The negative ``"<zero>"`` is the zero vector.
    """
    if templates and mode not in TEMPLATE_MODES:
        raise ConfigError(f"prompt_templates mode must be one of {TEMPLATE_MODES}; got {mode!r}.")
    strings = [*queryset.positives, *queryset.negatives]
    labels = np.asarray([1] * len(queryset.positives) + [0] * len(queryset.negatives))
    words = [s for s in strings if s != ZERO_TOKEN]
    reps = len(templates) if templates and mode == "all" else 1
    if not templates:
        W = encode_texts(encoder, words, cache)
        texts_of = {s: [s] for s in words}
    else:
        variants = [t.format(s) for s in words for t in templates]
        V = encode_texts(encoder, variants, cache).reshape(len(words), len(templates), -1)
        if mode == "all":
            W = V.reshape(len(variants), -1)
        else:
            W = V.mean(axis=1)
            W /= np.linalg.norm(W, axis=1, keepdims=True)
        texts_of = {s: ([t.format(s) for t in templates] if reps > 1 else [s]) for s in words}
    rows: list[np.ndarray] = []
    texts: list[str] = []
    row_of = {s: i for i, s in enumerate(words)}
    for s in strings:
        if s == ZERO_TOKEN:
            rows.append(np.zeros((reps, encoder.dim), dtype=np.float32))
            texts.extend([ZERO_TOKEN] * reps)
        else:
            i = row_of[s]
            rows.append(W[i * reps : (i + 1) * reps])
            texts.extend(texts_of[s])
    X = np.concatenate(rows).astype(np.float32, copy=False)
    y = np.repeat(labels, reps).astype(np.int64)
    return X, y, texts
