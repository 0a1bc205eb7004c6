"""Writing query results to files."""

from __future__ import annotations

import zipfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..core.atomic import atomic_dir, atomic_write, is_store_dir, refuse_own_input
from ..core.layout import layout_arrays, map_layout
from ..core.types import QueryResult

#: The arrays every results file has, as :func:`write_results_npz` writes them.
RESULT_ARRAYS = ("queries", "masks", "scores", "display_scores")
#: The arrays it may have besides: where each item is (copied from the map; a pixel map's
#: frames as ``quash convert`` writes them), and a JSON record of how the results were made.
OPTIONAL_RESULT_ARRAYS = (
    "positions",
    "grid_index",
    "frame_ids",
    "frame_hw",
    "frame_offsets",
    "up",
    "provenance",
)


def is_results_npz(path: str | Path) -> bool:
    """True when ``path`` is a results file written by :func:`write_results_npz`.

    Such a file may be replaced by a new result without ``--force``; anything else (a
    map, a file of the user's) may not.
    """
    try:
        with zipfile.ZipFile(path) as zf:
            names = set(zf.namelist())
    except (OSError, zipfile.BadZipFile):
        return False
    required = {f"{a}.npy" for a in RESULT_ARRAYS}
    allowed = required | {f"{a}.npy" for a in OPTIONAL_RESULT_ARRAYS}
    return required <= names <= allowed


def is_results_zarr(path: str | Path) -> bool:
    """True when ``path`` is a results store written by ``LazyQuery.to_zarr``."""
    p = Path(path)
    return is_store_dir(p) and (p / "masks").is_dir() and (p / "scores").is_dir()


def results_provenance(
    results: Sequence[QueryResult], encoder: Any = None, config_file: Any = None
) -> dict[str, Any]:
    """How ``results`` were made, as JSON-ready data: the package version, the map, the
    config (its name, and its file when it came from one) and its encoder, and per query
    its positives, negatives, heuristic (with its parameters: an LLM's model and endpoint,
    and whether the set came from the server or the cache) and the presence check's
    decision."""
    from .. import __version__

    first = results[0] if results else None
    out: dict[str, Any] = {
        "quash_plugins": __version__,
        "map": {
            k: v
            for k, v in (first.map_source if first else {}).items()
            if isinstance(v, (str, int, float, bool))
        },
        "config": first.config_name if first else "",
        "config_file": str(config_file) if config_file else None,
        "queries": [_query_record(r) for r in results],
    }
    if encoder is not None:
        out["encoder"] = {
            "name": getattr(encoder, "name", type(encoder).__name__),
            "fingerprint": encoder.fingerprint(),
        }
    return out


def _query_record(r: QueryResult) -> dict[str, Any]:
    """One query of :func:`results_provenance`: its set, the heuristic with its parameters
    and, for a set that can come from elsewhere (``llm``), where it came from (``source``:
    server or cache); for a label-list heuristic the query's ``label``, the list's source
    (``labels_from``) and how the query ``resolved`` to its label; the classifier, the
    match count and the presence decision."""
    prov = r.queryset.provenance or {}
    out: dict[str, Any] = {
        "query": r.query,
        "positives": list(r.queryset.positives),
        "negatives": list(r.queryset.negatives),
        "heuristic": prov.get("heuristic"),
    }
    if prov.get("params"):
        out["heuristic_params"] = prov["params"]
    if prov.get("source"):
        out["source"] = prov["source"]
    for key in ("label", "labels_from", "resolved"):  # a label-list heuristic's answer
        if key in prov:
            out[key] = prov[key]
    out.update(classifier=r.classifier, matched=r.n_matched, presence=r.presence)
    return out


def write_results_npz(
    path: str | Path,
    results: Sequence[QueryResult],
    lmap: Any = None,
    encoder: Any = None,
    config_file: Any = None,
    up: str | None = None,
) -> Path:
    """Write ``queries (Q,) str``, ``masks (Q, N) bool``, ``scores (Q, N) float32`` and
    ``display_scores (Q, N) float32`` atomically; row ``i`` of a mask is item ``i`` of
    the map (for a VLMaps map, row ``i`` of ``grid_feat``).

    Also written: ``provenance``, a 0-d JSON string (:func:`results_provenance`), and,
    given the map ``lmap``, its ``positions (N, 3)`` and ``grid_index (N, 3)`` where it
    has them, so the file alone can be plotted or put back on a grid; for a pixel map its
    frames (``frame_ids (F,)``, ``frame_hw (F, 2)``, ``frame_offsets (F,)``, as ``quash
    convert`` writes them), so each mask can be cut into per-image masks
    (``masks_per_frame(frames_from_npz(path), masks[q])``). With the positions goes
    their up axis, ``up`` (a 0-d string, ``"+y"``...), as the map's portable NPZ keeps
    it: ``up`` when given (``quash query --up``), else the one the map's ``source``
    records; none when neither says (``+z`` is then assumed).

    ``path`` may not be the map the results came from, nor any file read with it (the
    ``path`` and ``inputs`` of their ``map_source`` and of ``lmap.source``: VLMaps'
    ``obj2cls_dict.txt``, OpenScene's scene points, the taxonomy beside the map...),
    through any link: that is refused with
    :class:`~quash_plugins.core.errors.UsageError`, and nothing is written.
    """
    import json

    path = Path(path)
    sources = [r.map_source for r in results]
    if lmap is not None and isinstance(getattr(lmap, "source", None), dict):
        sources.append(lmap.source)
    refuse_own_input(path, sources)
    queries = np.asarray([r.query for r in results], dtype=str)
    masks = np.stack([r.mask for r in results]).astype(bool)
    scores = np.stack([r.scores for r in results]).astype(np.float32)
    display = np.stack([r.display_scores for r in results]).astype(np.float32)
    extra: dict[str, np.ndarray] = {}
    if lmap is not None:
        for key in ("positions", "grid_index"):
            value = getattr(lmap, key, None)
            if value is not None and len(value) == masks.shape[1]:
                extra[key] = np.asarray(value)
        layout = map_layout(lmap, up)  # the frames; the up axis goes with the positions
        if "positions" not in extra:
            layout.pop("up", None)
        extra.update(layout_arrays(layout))
    record = json.dumps(results_provenance(results, encoder, config_file), default=str)
    extra["provenance"] = np.asarray(record, dtype=str)
    with atomic_write(path, suffix=".npz") as tmp:
        np.savez(tmp, queries=queries, masks=masks, scores=scores, display_scores=display, **extra)
    return path


# ---------------------------------------------------------------------------------------
# OpenLex3D: per-query masks and scores beside its prediction layout

#: Files of :func:`write_results_openlex3d`.
OPENLEX3D_FILES = ("queries.json", "query_scores.npy", "query_scores_raw.npy", "query_masks.npy")


def is_openlex3d_results(path: str | Path) -> bool:
    """True for a folder written by :func:`write_results_openlex3d`, holding nothing else
    (it may be replaced whole): a file the user put in it (notes, a recording) would be
    lost, so such a folder is not replaced."""
    p = Path(path)
    if not (p.is_dir() and all((p / f).is_file() for f in OPENLEX3D_FILES[:2])):
        return False
    try:
        return {e.name for e in p.iterdir()} <= set(OPENLEX3D_FILES)
    except OSError:
        return False


def write_results_openlex3d(
    folder: str | Path, results: Sequence[QueryResult], map_source: dict | None = None
) -> Path:
    """Write per-query results for OpenLex3D-style evaluation, atomically, into ``folder``.

    Rows are the map's items in order: for a map exported with ``quash convert
    --format openlex3d`` (``index = arange``), the rows of ``embeddings.npy`` and the
    points of ``point_cloud.pcd``. Files:

    - ``query_scores.npy`` (N, Q) float32 in [0, 1]: each query's display scores, which
      rise with QuASH's decision value, sit at exactly 0.5 on its threshold and are 0
      for unobserved items. They play the part of OpenLex3D's normalised cosine: the
      top k by them are the top k by QuASH's score, and ``> 0.5`` is QuASH's mask;
    - ``query_scores_raw.npy`` (N, Q) float32: the decision values (``QueryResult.scores``);
    - ``query_masks.npy`` (N, Q) bool: QuASH's own masks (scores above the threshold);
    - ``queries.json``: the queries in column order, their query sets and counts.
    """
    import json

    folder = Path(folder).expanduser()
    n = len(results[0].mask) if results else 0
    scores = np.stack([np.asarray(r.display_scores, np.float32) for r in results], axis=1)
    raw = np.stack([np.asarray(r.scores, np.float32) for r in results], axis=1)
    masks = np.stack([np.asarray(r.mask, bool) for r in results], axis=1)
    meta = {
        "format": "quash-openlex3d-queries",
        "version": 1,
        "n_items": n,
        "rows": "the map's items in order (dense OpenLex3D export: embeddings.npy rows "
        "and point_cloud.pcd points)",
        "map": {k: v for k, v in (map_source or {}).items() if isinstance(v, (str, int, float))},
        "queries": [
            {
                "column": j,
                "query_text": r.query,
                "matched": r.n_matched,
                "threshold": r.threshold,
                "classifier": r.classifier,
                "config": r.config_name,
                "queryset": r.queryset.to_dict(),
            }
            for j, r in enumerate(results)
        ],
    }
    with atomic_dir(folder, replaceable=is_openlex3d_results, kind="query-results folder") as tmp:
        tmp.mkdir()
        np.save(tmp / "query_scores.npy", scores)
        np.save(tmp / "query_scores_raw.npy", raw)
        np.save(tmp / "query_masks.npy", masks)
        (tmp / "queries.json").write_text(json.dumps(meta, indent=2) + "\n", encoding="utf-8")
    return folder
