"""Transductive refinement: re-fit the classifier on the map's own confident items.

A classifier fitted on text embeddings alone sees only one modality; map embeddings sit
elsewhere (the modality gap). Refinement takes the first pass's most confident matches
as extra positives and a random sample of clearly unmatched items as extra negatives,
fits a second classifier on text + map samples, and classifies the map again. It never
uses ground truth. A first pass that matches fewer than ``min_seed`` items is kept as
it is, so an absent object stays absent.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from ..core.errors import ConfigError, check_options
from ..core.types import LatentMap, prepare_block

#: Where the map positives come from: the first pass's matches, or its best-scored items;
#: ``auto``: ``top`` for a query set from a label list (it records label groups), else
#: ``matched`` (see :func:`resolve_seeds`).
SEEDS = ("matched", "top", "auto")


def resolve_seeds(seeds: str, provenance: dict[str, Any]) -> str:
    """``seeds`` for one query set: ``auto`` is ``top`` when the query set has label
    groups (``provenance["negative_groups"]``: every other label a competitor), else
    ``matched``. With a label list the best-scored items are the query's object often
    enough to seed from; with only a vocabulary a refit on items of the wrong object
    ranks the map worse (docs/benchmarks.md), so only the first pass's matches seed it.

    Examples
    --------
    >>> resolve_seeds("auto", {"negative_groups": [3, 2]}), resolve_seeds("auto", {})
    ('top', 'matched')
    """
    if seeds != "auto":
        return seeds
    return "top" if provenance.get("negative_groups") else "matched"


@dataclass
class RefineOptions:
    """Options of the ``refine`` config section."""

    classifier: Any = "svm-rbf"
    n_positives: int = 100
    n_negatives: int = 1000
    negative_quantile: float = 0.5
    min_seed: int = 10
    seed: int = 0
    seeds: str = "matched"

    @classmethod
    def parse(cls, options: dict[str, Any]) -> RefineOptions:
        check_options("refine", options, [f.name for f in fields(cls)])
        opts = cls(**options)
        if opts.n_positives < 1 or opts.n_negatives < 1 or opts.min_seed < 1:
            raise ConfigError("refine: n_positives, n_negatives and min_seed must be >= 1.")
        if not 0.0 < opts.negative_quantile <= 1.0:
            raise ConfigError("refine: negative_quantile must be in (0, 1].")
        if opts.seeds not in SEEDS:
            raise ConfigError(f"refine: seeds must be one of {SEEDS}; got {opts.seeds!r}.")
        return opts

    def build_classifier(self) -> Any:
        from ..core import registry

        spec = self.classifier
        if isinstance(spec, str):
            return registry.create("classifiers", spec)
        if not isinstance(spec, dict) or "name" not in spec:
            raise ConfigError("refine: 'classifier' must be a name or {name: ..., <param>: ...}.")
        params = {k: v for k, v in spec.items() if k != "name"}
        return registry.create("classifiers", spec["name"], **params)


#: Bytes of stored rows :func:`take_rows` reads at once from a chunked store (zarr).
TAKE_WINDOW_BYTES = 16 * 2**20


def take_rows(lmap: LatentMap, index: np.ndarray) -> np.ndarray:
    """Rows ``index`` of the map's embeddings as ``(k, D)`` float32, prepared as the
    classification pass prepares them (normalised when the map asks for it).

    A zarr array is read window by window (:data:`TAKE_WINDOW_BYTES` of rows, plus the
    stored chunks a window overlaps), never with one fancy index: zarr decodes every
    stored chunk that scattered rows touch at once. Taking 1,100 scattered rows
    (refinement's samples; the presence check's regions read rows the same way) from a
    200,000 x 384 float32 store in 16 MiB chunks peaked at 247 MiB that way, 79 MiB so.
    """
    index = np.unique(np.asarray(index, dtype=np.int64))
    emb = lmap.embeddings
    if type(emb).__module__.startswith("zarr") and len(index):
        return prepare_block(_take_windowed(emb, index, lmap.dim), 0, lmap.normalize, lmap.source)
    try:
        rows = emb[index]
        rows = rows.compute() if hasattr(rows, "compute") else rows
        block = np.asarray(rows, dtype=np.float32)
        if block.shape != (len(index), lmap.dim):
            raise ValueError
    except (TypeError, ValueError, IndexError):
        # Array-likes without fancy indexing: read the covering row range by range.
        parts = []
        for start in range(0, len(index), 4096):
            part = index[start : start + 4096]
            lo, hi = int(part[0]), int(part[-1]) + 1
            parts.append(np.asarray(emb[lo:hi], dtype=np.float32)[part - lo])
        block = np.concatenate(parts)
    return prepare_block(np.array(block, dtype=np.float32), 0, lmap.normalize, lmap.source)


def _take_windowed(emb: Any, index: np.ndarray, dim: int) -> np.ndarray:
    """Rows ``index`` (sorted, unique) of ``emb``, reading one window of rows at a time:
    each window is the slice from its first to its last wanted row, at most
    :data:`TAKE_WINDOW_BYTES` of float32 rows long."""
    window = max(1, TAKE_WINDOW_BYTES // (4 * max(1, int(dim))))
    out = np.empty((len(index), dim), dtype=np.float32)
    i = 0
    while i < len(index):
        lo = int(index[i])
        j = int(np.searchsorted(index, lo + window, side="left"))
        hi = int(index[j - 1]) + 1
        out[i:j] = np.asarray(emb[lo:hi], dtype=np.float32)[index[i:j] - lo]
        i = j
    return out


def pseudo_labels(
    lmap: LatentMap,
    scores: np.ndarray,
    mask: np.ndarray,
    observed: np.ndarray,
    opts: RefineOptions,
    salt: str,
    seeds: str | None = None,
) -> tuple[np.ndarray, np.ndarray] | None:
    """Map samples ``(k, D)`` and labels ``(k,)`` from a first pass, or None to keep it.

    Positives: the ``n_positives`` highest-scoring matched items (``seeds: top``: the
    ``n_positives`` highest-scoring observed items, matched or not, so that a class whose
    text sits just off its map items still seeds). Negatives: a seeded random sample of
    observed items scoring below the ``negative_quantile`` of the observed scores (and
    not positives). ``salt`` seeds the draw with ``opts.seed``: the query's label when it
    resolves to one, else its text. ``seeds`` overrides ``opts.seeds`` (resolved for the
    query set, :func:`resolve_seeds`).
    """
    seeds = seeds or opts.seeds
    if seeds == "auto":
        raise ValueError("resolve seeds: auto for the query set first (resolve_seeds)")
    if seeds == "top":
        obs_idx = np.flatnonzero(observed)
        if len(obs_idx) < 2 * opts.min_seed:
            return None
        top = obs_idx[np.argsort(-scores[obs_idx], kind="stable")[: opts.n_positives]]
        taken = np.zeros(len(mask), bool)
        taken[top] = True
    else:
        matched = np.flatnonzero(mask)
        if len(matched) < opts.min_seed:
            return None
        top = matched[np.argsort(-scores[matched], kind="stable")[: opts.n_positives]]
        taken = mask
    obs = np.flatnonzero(observed & ~taken)
    if len(obs) == 0:
        return None
    cut = np.quantile(scores[observed], opts.negative_quantile)
    pool = obs[scores[obs] <= cut]
    if len(pool) == 0:
        return None
    digest = hashlib.sha256(f"{opts.seed}|{salt}".encode()).digest()
    rng = np.random.default_rng(int.from_bytes(digest[:8], "little"))
    neg = rng.choice(pool, size=min(opts.n_negatives, len(pool)), replace=False)
    rows = take_rows(lmap, np.concatenate([top, neg]))
    # take_rows sorts; rebuild labels in that order
    order = np.unique(np.concatenate([top, neg]))
    y = np.isin(order, top).astype(np.int64)
    return rows, y
