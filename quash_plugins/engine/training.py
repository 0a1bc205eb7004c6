"""Turning a :class:`QuerySet` into a training set ``X (n, D)``, ``y (n,)``."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from ..core.errors import ConfigError
from ..core.interfaces import Encoder
from ..core.text import TEMPLATE_MODES, ZERO_TOKEN, TextCache, encode_texts, encoder_dim
from ..core.types import QuerySet

#: Most distinct strings embedded in one encoder call by :func:`training_sets`; query
#: sets beyond it go to further calls, so memory stays bounded for any number of queries.
MAX_STRINGS_PER_CALL = 200_000


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
    return training_sets(encoder, [queryset], cache, templates, mode, normalize)[0]


def training_sets(
    encoder: Encoder,
    querysets: Sequence[QuerySet],
    cache: TextCache | None = None,
    templates: Sequence[str] | None = None,
    mode: str = "mean",
    normalize: bool = True,
    progress: Callable[[int], None] | None = None,
) -> list[tuple[np.ndarray, np.ndarray, list[str]]]:
    """:func:`training_set` for many query sets, with one encoder call for all of them.

    The strings of every query set (and their templated variants) are gathered, each
    distinct one is embedded once (one cache lookup, one call into the encoder, one
    cache write), and each set's ``X, y`` is assembled from that table. Up to
    :data:`MAX_STRINGS_PER_CALL` distinct strings go in one call; more are split between
    calls at query-set boundaries. ``progress(k)`` is called after each group of ``k``
    query sets.
    """
    if templates and mode not in TEMPLATE_MODES:
        raise ConfigError(f"prompt_templates mode must be one of {TEMPLATE_MODES}; got {mode!r}.")
    out: list[tuple[np.ndarray, np.ndarray, list[str]]] = []
    group: list[QuerySet] = []
    needed: dict[str, None] = {}

    def flush() -> None:
        texts = list(needed)
        table = dict(zip(texts, encode_texts(encoder, texts, cache))) if texts else {}
        out.extend(_assemble(encoder, qs, table, templates, mode, normalize) for qs in group)
        if progress is not None:
            progress(len(group))
        group.clear()
        needed.clear()

    for qs in querysets:
        strings = _strings_to_embed(qs, templates)
        new = [t for t in strings if t not in needed]
        if group and len(needed) + len(new) > MAX_STRINGS_PER_CALL:
            flush()
            new = strings
        group.append(qs)
        needed.update(dict.fromkeys(new))
    if group:
        flush()
    return out


def _words(qs: QuerySet) -> list[str]:
    return [s for s in [*qs.positives, *qs.negatives] if s != ZERO_TOKEN]


def _strings_to_embed(qs: QuerySet, templates: Sequence[str] | None) -> list[str]:
    words = _words(qs)
    if not templates:
        return words
    return [t.format(s) for s in words for t in templates]


def _assemble(
    encoder: Encoder,
    queryset: QuerySet,
    table: dict[str, np.ndarray],
    templates: Sequence[str] | None,
    mode: str,
    normalize: bool = True,
) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """One query set's ``X, y, texts`` from embedded strings ``table``."""
    strings = [*queryset.positives, *queryset.negatives]
    labels = np.asarray([1] * len(queryset.positives) + [0] * len(queryset.negatives))
    words = _words(queryset)
    reps = len(templates) if templates and mode == "all" else 1
    dim = encoder_dim(encoder)
    if not templates:
        W = _stack([table[s] for s in words], dim)
        texts_of = {s: [s] for s in words}
    else:
        variants = [t.format(s) for s in words for t in templates]
        V = _stack([table[v] for v in variants], dim).reshape(len(words), len(templates), -1)
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
            rows.append(np.zeros((reps, dim), dtype=np.float32))
            texts.extend([ZERO_TOKEN] * reps)
        else:
            i = row_of[s]
            rows.append(W[i * reps : (i + 1) * reps])
            texts.extend(texts_of[s])
    X = np.concatenate(rows).astype(np.float32, copy=False)
    y = np.repeat(labels, reps).astype(np.int64)
    return X, y, texts


def _stack(vectors: list[np.ndarray], dim: int) -> np.ndarray:
    if not vectors:
        return np.zeros((0, dim), dtype=np.float32)
    return np.stack(vectors).astype(np.float32, copy=False)


class CallCache:
    """An in-memory text-embedding cache for one call, in front of the persistent one.

    ``Quash.query_many`` embeds every query in one encoder call into it, so that
    heuristics that embed their query (``vocabulary``, the label resolution of
    ``taxonomy``) find it there instead of calling the encoder once per query; then the
    query sets' strings go through it in one more call. ``persistent`` (the on-disk
    cache, or None) is read once per string and written once per call.
    """

    def __init__(self, persistent: TextCache | None = None) -> None:
        self.persistent = persistent
        self._mem: dict[str, dict[str, np.ndarray]] = {}

    def lookup(self, fingerprint: str, texts: Sequence[str]) -> dict[str, np.ndarray]:
        mem = self._mem.setdefault(fingerprint, {})
        found = {t: mem[t] for t in texts if t in mem}
        missing = [t for t in dict.fromkeys(texts) if t not in found]
        if missing and self.persistent is not None:
            more = self.persistent.lookup(fingerprint, missing)
            mem.update(more)
            found.update(more)
        return found

    def store(self, fingerprint: str, embeddings: dict[str, np.ndarray]) -> None:
        self._mem.setdefault(fingerprint, {}).update(embeddings)
        if self.persistent is not None:
            self.persistent.store(fingerprint, embeddings)
