"""Turning a :class:`QuerySet` into a training set ``X (n, D)``, ``y (n,)``."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..core.errors import ConfigError
from ..core.interfaces import Encoder
from ..core.text import TEMPLATE_MODES, ZERO_TOKEN, TextCache, encode_texts
from ..core.types import QuerySet


def training_set(
    encoder: Encoder,
    queryset: QuerySet,
    cache: TextCache | None = None,
    templates: Sequence[str] | None = None,
    mode: str = "mean",
    normalize: bool = True,
) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Encode a query set into ``X (n, D)`` float32, ``y (n,)`` int and the row texts.

    Positives come first (the query itself first of all), then negatives. With
    ``templates``, ``mode="mean"`` replaces each string by the mean of its templated
    embeddings (each unit-norm, from the encoder), re-normalised unless
    ``normalize=False``: VLMaps does not re-normalise, so its text vectors keep norms
    below one that differ per label. ``mode="all"`` makes every templated variant a
    sample. The negative ``"<zero>"`` is the zero vector.
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
            if normalize:
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
