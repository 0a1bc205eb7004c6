"""Display-only helpers: deterministic thinning, PCA colours, colormaps, slugs.

Nothing here touches what a query computes; these functions only decide what is drawn.
"""

from __future__ import annotations

import re

import numpy as np

from ..core.types import UP_AXES as AXES
from ..core.types import LatentMap

#: Rows read per block when projecting embeddings for PCA colours.
_PCA_BLOCK_ROWS = 65_536

#: Small viridis-like lookup table used when matplotlib is not installed.
_FALLBACK_LUT = np.array(
    [
        [68, 1, 84],
        [72, 40, 120],
        [62, 74, 137],
        [49, 104, 142],
        [38, 130, 142],
        [31, 158, 137],
        [53, 183, 121],
        [109, 205, 89],
        [180, 222, 44],
        [253, 231, 37],
    ],
    dtype=np.float32,
)


def display_indices(n: int, limit: int) -> np.ndarray | None:
    """Indices of the items drawn when a layer has ``n`` items and may draw ``limit``.

    Returns None when every item is drawn. Otherwise returns ``(limit,)`` int64 sorted,
    evenly strided indices: deterministic (the same map always shows the same items)
    and spread over the whole map, including the last item.

    >>> display_indices(10, 20) is None
    True
    >>> display_indices(10, 4).tolist()
    [0, 3, 6, 9]
    """
    if limit <= 0 or n <= limit:
        return None
    return np.unique(np.linspace(0, n - 1, int(limit)).round().astype(np.int64))


def thin(indices: np.ndarray, limit: int) -> np.ndarray:
    """Keep at most ``limit`` entries of ``indices`` (evenly strided, deterministic)."""
    keep = display_indices(len(indices), limit)
    return indices if keep is None else indices[keep]


#: A result's outcome against its query's ground truth, per item (``outcomes``): none (not
#: drawn), true positive, false positive, false negative, and matched but not scored (an
#: unlabelled item, or one of a label the evaluation excludes).
OUTCOME_NONE, OUTCOME_TP, OUTCOME_FP, OUTCOME_FN, OUTCOME_UNSCORED = range(5)

#: The colours of the outcomes (Okabe-Ito, told apart with any colour vision): true
#: positives blue, false positives vermillion, false negatives yellow. A match that is not
#: scored keeps the match colour (magenta, ``_log_map.MATCH_COLOR``).
OUTCOME_COLORS = {
    OUTCOME_TP: (0, 114, 178),
    OUTCOME_FP: (213, 94, 0),
    OUTCOME_FN: (240, 228, 66),
}

#: The outcomes' colours and meanings in words, for the legend of a query's document.
OUTCOME_WORDS = {
    OUTCOME_TP: ("blue", "true positives (matched, of the label)"),
    OUTCOME_FP: ("vermillion", "false positives (matched, not of the label)"),
    OUTCOME_FN: ("yellow", "false negatives (of the label, not matched)"),
    OUTCOME_UNSCORED: ("magenta", "matched but not scored (unlabelled or excluded)"),
}


def outcomes(mask: np.ndarray, truth: np.ndarray, counted: np.ndarray | None = None) -> np.ndarray:
    """``(N,) uint8``: each item's outcome (``OUTCOME_*``) for the predicted ``mask``
    against the ground truth ``truth``; ``counted`` (None: every item) are the items an
    evaluation scores, the others are neither right nor wrong (a match there is
    ``OUTCOME_UNSCORED``, a miss nothing). An absence query's ``truth`` is all False, so
    every counted match is a false positive.

    >>> outcomes(np.array([1, 1, 0, 0, 1], bool), np.array([1, 0, 1, 0, 0], bool),
    ...          np.array([1, 1, 1, 1, 0], bool)).tolist()
    [1, 2, 3, 0, 4]
    """
    mask = np.asarray(mask, bool)
    truth = np.asarray(truth, bool)
    if truth.shape != mask.shape:
        raise ValueError(f"truth has {truth.shape[0]} items, the result {mask.shape[0]}")
    ok = np.ones_like(mask) if counted is None else np.asarray(counted, bool)
    if ok.shape != mask.shape:
        raise ValueError(f"counted has {ok.shape[0]} items, the result {mask.shape[0]}")
    out = np.zeros(mask.shape, np.uint8)
    out[mask & ~ok] = OUTCOME_UNSCORED
    out[mask & ok & truth] = OUTCOME_TP
    out[mask & ok & ~truth] = OUTCOME_FP
    out[~mask & ok & truth] = OUTCOME_FN
    return out


#: Up axes a map can declare (:data:`~quash_plugins.core.types.UP_AXES`), as (axis
#: index, sign): ``"-y"`` is ``(1, -1.0)``.
UP_AXES = {a: ("xyz".index(a[1]), 1.0 if a[0] == "+" else -1.0) for a in AXES}


def map_up(up: str | None, source: dict | None) -> str | None:
    """The up axis to draw a map with: ``up`` itself, or for ``"auto"`` the one the map's
    adapter recorded (``source["up"]``: ``"+y"`` for VLMaps camera-base maps), else ``"+z"``.

    >>> map_up("auto", {"up": "+y"}), map_up("auto", {}), map_up("-y", {"up": "+y"})
    ('+y', '+z', '-y')
    """
    if up != "auto":
        return up
    recorded = (source or {}).get("up")
    return recorded if recorded in UP_AXES else "+z"


def ceiling_items(
    positions: np.ndarray,
    voxel_size: float | None,
    up: str = "+z",
    min_share: float = 0.08,
    min_height: float = 1.5,
) -> np.ndarray | None:
    """Boolean mask of the items that form a ceiling, or None when the map has none.

    A ceiling is a horizontal layer at the very top of a map at least ``min_height``
    metres high (within half a voxel, or 3 % of the height, of the highest item) that
    holds at least ``min_share`` of the items and spans at least half of the map's
    footprint on both horizontal axes. Indoor scans and the demo scene have one; seen
    from above it hides every room, so the viewer logs it apart and hides it by default.

    >>> grid = np.stack(np.meshgrid(np.arange(4), np.arange(4), np.arange(3), indexing="ij"), -1)
    >>> room = grid.reshape(-1, 3).astype(np.float32)  # 1 m voxels, 2 m high
    >>> ceiling_items(room, 1.0).reshape(4, 4, 3)[0, 0].tolist()
    [False, False, True]
    >>> ceiling_items(room * 0.1, 0.1) is None  # 0.2 m high: a block, not a room
    True
    """
    if up not in UP_AXES or len(positions) < 10:
        return None
    axis, sign = UP_AXES[up]
    height = sign * np.asarray(positions[:, axis], dtype=np.float64)
    top, span = float(height.max()), float(np.ptp(height))
    if span < min_height:
        return None
    tol = max(0.5 * float(voxel_size or 0.0), 0.03 * span)
    layer = height >= top - tol
    if layer.mean() < min_share or layer.all():
        return None
    flat = [a for a in range(3) if a != axis]
    for a in flat:
        full = float(np.ptp(positions[:, a]))
        if full > 0 and float(np.ptp(positions[layer, a])) < 0.5 * full:
            return None
    return layer


def first_match_class(n_classes: int) -> int:
    """The first of ``n_classes`` score classes labelled a match: the first class ``i``
    whose display score ``i / (n_classes - 1)`` is at or above 0.5, the threshold.

    >>> first_match_class(32), first_match_class(11), first_match_class(2)
    (16, 5, 1)
    """
    return int(n_classes) // 2


def score_classes(values: np.ndarray, n_classes: int) -> np.ndarray:
    """``(M,)`` display scores in [0, 1] to class ids ``0 .. n_classes - 1`` (uint16).

    Class ``i`` is the display score ``i / (n_classes - 1)`` (``np.rint``), except at the
    threshold, which is always a class boundary: a score at or above 0.5 is in a match
    class (:func:`first_match_class` and up), one below 0.5 never is. With an even count
    the rounding already does that; with an odd one, the class at exactly 0.50 would
    also take the scores from ``0.5 - 0.5 / (n_classes - 1)`` to 0.5: those go to the
    class below it.

    >>> score_classes(np.array([0.0, 0.5, 1.0, np.nan]), 5).tolist()
    [0, 2, 4, 0]
    >>> score_classes(np.array([0.45, 0.4999, 0.5, 0.54]), 11).tolist()
    [4, 4, 5, 5]
    """
    v = np.clip(np.nan_to_num(np.asarray(values, dtype=np.float32), nan=0.0), 0.0, 1.0)
    ids = np.rint(v * (n_classes - 1)).astype(np.int64)
    first = first_match_class(n_classes)
    ids = np.where(v >= np.float32(0.5), np.maximum(ids, first), np.minimum(ids, first - 1))
    return ids.astype(np.uint16)


def slugify(text: str, fallback: str = "query") -> str:
    """Entity-path-safe name for a query: lowercase ASCII words joined by ``_``.

    >>> slugify("Red  Chair!")
    'red_chair'
    """
    slug = re.sub(r"[^a-z0-9]+", "_", text.lower()).strip("_")
    return slug[:64] or fallback


def _read_rows(lmap: LatentMap, idx: np.ndarray) -> np.ndarray:
    """``(len(idx), D)`` float32 rows at sorted ``idx``, normalised when the map asks."""
    from ..core.types import prepare_block

    emb = lmap.embeddings
    if len(idx) and idx[-1] - idx[0] + 1 == len(idx):
        block = np.asarray(emb[int(idx[0]) : int(idx[-1]) + 1], dtype=np.float32)
    else:
        block = np.asarray(emb[idx], dtype=np.float32)
    x = np.array(block, dtype=np.float32)  # a copy: normalised in place
    return prepare_block(x, 0, lmap.normalize, lmap.source, owned=True)


def pca_colors(
    lmap: LatentMap, items: np.ndarray | None = None, sample: int = 20_000, seed: int = 0
) -> np.ndarray:
    """Colour items by the first three principal components of their embeddings.

    The components are fitted on at most ``sample`` rows (a seeded, sorted subsample)
    and the projection is done in blocks, so the embeddings are never read whole.

    Parameters
    ----------
    lmap
        The map.
    items
        ``(M,)`` sorted item indices to colour, or None for all ``N`` items.

    Returns
    -------
    ``(M, 3)`` uint8 colours; unobserved (all-zero) rows are mid grey.
    """
    n = lmap.n
    items = np.arange(n, dtype=np.int64) if items is None else np.asarray(items, np.int64)
    if n == 0 or len(items) == 0:  # an empty map, or nothing to colour
        return np.empty((len(items), 3), dtype=np.uint8)
    rng = np.random.default_rng(seed)
    fit_idx = np.sort(rng.choice(n, size=min(n, sample), replace=False))
    fit = _read_rows(lmap, fit_idx)
    observed = np.abs(fit).sum(axis=1) > 0
    fit = fit[observed] if observed.any() else fit
    mean = fit.mean(axis=0)
    centred = fit - mean
    if len(fit) >= 2:
        _, _, vt = np.linalg.svd(centred, full_matrices=False)
        comps = vt[:3]
    else:
        comps = np.eye(3, lmap.dim, dtype=np.float32)
    if comps.shape[0] < 3:
        comps = np.vstack([comps, np.zeros((3 - comps.shape[0], lmap.dim), np.float32)])
    proj_fit = centred @ comps.T
    lo = np.percentile(proj_fit, 2, axis=0)
    hi = np.percentile(proj_fit, 98, axis=0)
    span = np.where(hi - lo > 1e-12, hi - lo, 1.0)
    out = np.empty((len(items), 3), dtype=np.uint8)
    for start in range(0, len(items), _PCA_BLOCK_ROWS):
        idx = items[start : start + _PCA_BLOCK_ROWS]
        rows = _read_rows(lmap, idx)
        proj = (rows - mean) @ comps.T
        rgb = np.clip((proj - lo) / span, 0.0, 1.0) * 255.0
        rgb[np.abs(rows).sum(axis=1) == 0] = 128.0
        out[start : start + len(idx)] = np.rint(rgb).astype(np.uint8)
    return out


def colormap(values: np.ndarray, name: str = "viridis") -> np.ndarray:
    """``(M,)`` values in [0, 1] to ``(M, 3)`` uint8 colours under a colormap.

    Uses matplotlib's colormap ``name`` when matplotlib is installed, else a built-in
    viridis-like table.
    """
    v = np.clip(np.nan_to_num(np.asarray(values, dtype=np.float32), nan=0.0), 0.0, 1.0)
    try:
        from matplotlib import colormaps

        rgba = colormaps[name](v)
        return np.rint(np.asarray(rgba)[..., :3] * 255.0).astype(np.uint8)
    except (ImportError, KeyError):
        pos = v * (len(_FALLBACK_LUT) - 1)
        lo = np.floor(pos).astype(np.int64)
        hi = np.minimum(lo + 1, len(_FALLBACK_LUT) - 1)
        t = (pos - lo)[..., None]
        rgb = _FALLBACK_LUT[lo] * (1.0 - t) + _FALLBACK_LUT[hi] * t
        return np.rint(rgb).astype(np.uint8)
