"""Drop-in QuASH for VLMaps projects.

VLMaps answers ``VLMap.index_map(language_desc, with_init_cat=True)`` with an ``(N,)``
bool mask over the rows of ``vlmap.grid_feat``: a row matches when the query's text
embedding (the mean over VLMaps' prompt templates, not re-normalised) scores highest
among ``[categories..., "other"]`` (with ``with_init_cat=True`` and categories set by
``init_categories``; VLMaps raises when there are none) or among
``[language_desc, "other"]`` otherwise. VLMaps' ``get_pos`` (and everything built on it:
``get_nearest_pos``, the navigation primitives) calls ``index_map``, but also asserts
``self.categories`` first, so patching ``index_map`` removes the need for categories
only for ``index_map`` itself.

This module returns a mask with the same meaning and shape, decided by QuASH instead:

* :func:`index_map` ``(vlmap, text, with_init_cat=True, quash=...)`` -> ``(N,)`` bool;
* :func:`patch_vlmap` replaces ``index_map`` on one VLMap object, so the rest of VLMaps
  uses QuASH unchanged; :func:`unpatch_vlmap` restores it;
* :class:`QuashIndexMixin` does the same for a subclass;
* :func:`query` returns the full :class:`~quash_plugins.core.types.QueryResult` (scores,
  instances with centroids in metres).

With ``with_init_cat=True`` and ``vlmap.categories`` set, the other categories are added
to the query's negatives in VLMaps' column order (those listed before the query first;
a query names a category up to case, ``_``, ``-`` and spacing: "tv monitor" is ``tv_monitor``),
which mirrors VLMaps' argmax over the category list; a classifier with a
``query_column`` parameter (``label-argmax``) is told how many come before the query,
so ties go to the earlier column as in VLMaps. Unlike VLMaps, a missing category list
is not an error: the query then stands on its own. Zero rows of ``grid_feat`` never
match.

Examples
--------
>>> import numpy as np
>>> from types import SimpleNamespace
>>> vlmap = SimpleNamespace(grid_feat=np.array([[1, 0.1], [0.1, 1], [0, 0]], np.float32),
...                         grid_pos=np.array([[500, 500, 0], [501, 500, 0], [502, 500, 0]]))
>>> cfg = {"encoder": {"name": "table", "table": {"chair": [1, 0], "other": [0, 1],
...        "background": [0, 1], "nothing": [0, 1]}}, "classifier": "contrast", "cache": False}
>>> index_map(vlmap, "chair", quash=cfg).tolist()
[True, False, False]
"""

from __future__ import annotations

import contextlib
import copy
import logging
import types
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from sklearn.base import clone

from ..core.config import VLMAPS_MAP_CONFIG_KEYS
from ..core.errors import MapFormatError, QuashError
from ..core.types import LatentMap, QueryResult, check_query
from ..engine.map_fit import warn_unused_adapter_options

log = logging.getLogger(__name__)

__all__ = ["index_map", "query", "patch_vlmap", "unpatch_vlmap", "QuashIndexMixin", "as_latent_map"]

_CACHE_ATTR = "_quash_latent_map"
_QUASH_ATTR = "_quash"
_ORIGINAL_ATTR = "_vlmaps_index_map"
#: What the live adapter reads of a VLMap besides its arrays: a change reads the map anew.
_LIVE_SETTINGS = ("cs", "gs", "pcd_min", "map_config", "map_save_path")


def resolve_quash(quash: Any, vlmap: Any = None) -> Any:
    """A :class:`~quash_plugins.engine.pipeline.Quash` from an instance, a config or the VLMap.

    ``quash`` may be a ``Quash``, a :class:`~quash_plugins.core.config.QuashConfig`, a mapping
    (a dict, or an OmegaConf ``DictConfig``: a section of a Hydra config, as VLMaps' own
    configs are), or a path to a YAML config. ``None`` uses the one attached by :func:`patch_vlmap`.
    """
    from ..core.config import QuashConfig
    from ..engine.pipeline import Quash

    if quash is None and vlmap is not None:
        quash = getattr(vlmap, _QUASH_ATTR, None) or getattr(vlmap, "quash", None)
    if quash is None:
        raise QuashError(
            "No QuASH configuration given. Pass quash=CONFIG (a YAML path, a dict or a Quash) "
            "or attach one first with patch_vlmap(vlmap, CONFIG)."
        )
    if isinstance(quash, Quash):
        return quash
    if isinstance(quash, Mapping):
        quash = _plain(quash)  # an OmegaConf DictConfig: a section of the project's Hydra config
        vlmaps_keys = sorted(VLMAPS_MAP_CONFIG_KEYS & set(quash))
        if vlmaps_keys:
            raise QuashError(
                f"quash= got VLMaps' map config (it has {', '.join(vlmaps_keys)}), not a QuASH "
                "config. Pass the QuASH config instead (a YAML path such as 'quash.yaml', or "
                "its section of your config): the map's grid and cell size come from the VLMap."
            )
    if isinstance(quash, (str, Path, dict, QuashConfig)):
        return Quash.from_config(quash)
    raise QuashError(
        "quash must be a Quash, a QuashConfig, a mapping (a dict, or a section of your Hydra "
        f"config) or a YAML path; got {type(quash).__name__}."
    )


def _plain(value: Any) -> Any:
    """Mappings and sequences (OmegaConf's DictConfig and ListConfig) as dicts and lists."""
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, Sequence) and not isinstance(value, (str, bytes)):
        return [_plain(v) for v in value]
    return value


def as_latent_map(vlmap: Any, **options: Any) -> LatentMap:
    """The live VLMap as a :class:`LatentMap`, cached on the object until its arrays or
    its settings (``cs``, ``gs``, ``pcd_min``, ``map_config``, ``map_save_path``) change.

    ``options`` are those of the ``vlmaps-live`` adapter (``gs``, ``cs``, ``pose_type``,
    ``label_names``).
    """
    from ..adapters import VLMapsLiveAdapter

    feat = getattr(vlmap, "grid_feat", None)
    pos = getattr(vlmap, "grid_pos", None)
    settings = tuple(repr(getattr(vlmap, name, None)) for name in _LIVE_SETTINGS)
    key = (id(feat), getattr(feat, "shape", None), id(pos), repr(sorted(options.items())), settings)
    cached = getattr(vlmap, _CACHE_ATTR, None)
    if cached is not None and cached[0] == key:
        return cached[1]
    lmap = VLMapsLiveAdapter().read(vlmap, **options)
    with contextlib.suppress(AttributeError):  # __slots__ objects: no cache, still correct
        setattr(vlmap, _CACHE_ATTR, (key, lmap))
    return lmap


def _category_key(name: str) -> str:
    """A name as compared with the categories: case, ``_``/``-`` and spacing ignored.

    VLMaps' category lists spell names with underscores (``mp3dcat``: ``chest_of_drawers``,
    ``tv_monitor``), so the query "tv monitor" is the category ``tv_monitor``; kept as a
    negative, the category would take the query's own rows.
    """
    return " ".join(name.replace("_", " ").replace("-", " ").split()).casefold()


def _other_categories(vlmap: Any, text: str) -> tuple[list[str], int]:
    """The categories other than ``text`` in VLMaps' order, and how many precede it.

    A query that is not a category (VLMaps would ask a language model for the closest
    one) is a label of its own in column 0.
    """
    cats = [str(c) for c in (getattr(vlmap, "categories", None) or [])]
    low = _category_key(text)
    hits = [i for i, c in enumerate(cats) if _category_key(c) == low]
    others = [c for c in cats if _category_key(c) != low]
    before = len([c for c in cats[: hits[0]] if _category_key(c) != low]) if hits else 0
    return others, before


def query(
    vlmap: Any,
    language_desc: str,
    with_init_cat: bool = True,
    quash: Any = None,
    **read_options: Any,
) -> QueryResult:
    """Answer ``language_desc`` over a live VLMap with QuASH; the full result.

    Parameters
    ----------
    vlmap
        A VLMaps ``VLMap`` (or any object with ``grid_feat`` and ``grid_pos``).
    language_desc
        The query, e.g. ``"chair"``.
    with_init_cat
        Add ``vlmap.categories`` (other than the query) to the negatives when present.
    quash
        A ``Quash``, a config (dict, ``QuashConfig`` or YAML path), or None for the one
        attached by :func:`patch_vlmap`.
    read_options
        Options of the ``vlmaps-live`` adapter (``gs``, ``cs``, ``pose_type``).

    Returns
    -------
    QueryResult
        ``mask`` and ``scores`` are ``(N,)`` over the rows of ``vlmap.grid_feat``.
    """
    language_desc = check_query(language_desc)  # a list, None...: refused before the categories
    if isinstance(vlmap, (str, Path)):
        raise MapFormatError(
            f"{vlmap}: index_map and query take a live VLMap object (after VLMap.load_map), "
            f"not a path. For the map on disk use Quash.from_config(CONFIG).query({str(vlmap)!r}, "
            "TEXT), or quash query PATH TEXT -c CONFIG."
        )
    q = resolve_quash(quash, vlmap)
    lmap = as_latent_map(vlmap, **read_options)
    warn_unused_adapter_options(getattr(q, "adapter", None), lmap, vlmap, read_options)
    extra, before = _other_categories(vlmap, language_desc) if with_init_cat else ([], 0)
    if extra:
        q = copy.copy(q)
        # VLMaps' columns are [categories..., "other"]: the categories go first, in order.
        q.negatives = [*extra, *[n for n in q.negatives if n not in extra]]
        params = q.classifier.get_params() if hasattr(q.classifier, "get_params") else {}
        if "query_column" in params:
            q.classifier = clone(q.classifier).set_params(query_column=before)
        q._querysets = {}  # the copy must not reuse query sets built without these negatives
    return q.query(lmap, language_desc)


def index_map(
    vlmap: Any,
    language_desc: str,
    with_init_cat: bool = True,
    quash: Any = None,
    **read_options: Any,
) -> np.ndarray:
    """QuASH's answer to ``VLMap.index_map``: an ``(N,)`` bool mask over ``grid_feat`` rows.

    Same arguments as :func:`query`; returns ``query(...).mask``.
    """
    return query(vlmap, language_desc, with_init_cat, quash, **read_options).mask


def patch_vlmap(vlmap: Any, quash: Any) -> Any:
    """Make ``vlmap.index_map`` (and so ``get_pos`` & co.) answer with QuASH.

    The original method is kept and restored by :func:`unpatch_vlmap`. Returns ``vlmap``.
    """
    resolved = resolve_quash(quash)
    if not hasattr(vlmap, _ORIGINAL_ATTR):
        setattr(vlmap, _ORIGINAL_ATTR, getattr(vlmap, "index_map", None))
    setattr(vlmap, _QUASH_ATTR, resolved)

    def _index_map(self: Any, language_desc: str, with_init_cat: bool = True) -> np.ndarray:
        return index_map(self, language_desc, with_init_cat, quash=getattr(self, _QUASH_ATTR))

    vlmap.index_map = types.MethodType(_index_map, vlmap)
    return vlmap


def unpatch_vlmap(vlmap: Any) -> Any:
    """Undo :func:`patch_vlmap`; returns ``vlmap``."""
    if hasattr(vlmap, _ORIGINAL_ATTR):
        original = getattr(vlmap, _ORIGINAL_ATTR)
        del vlmap.index_map  # the instance attribute; the class method shows again
        if original is not None and getattr(vlmap, "index_map", None) is None:
            vlmap.index_map = original
        delattr(vlmap, _ORIGINAL_ATTR)
    for attr in (_QUASH_ATTR, _CACHE_ATTR):
        if hasattr(vlmap, attr):
            delattr(vlmap, attr)
    return vlmap


class QuashIndexMixin:
    """Mixin whose ``index_map`` is decided by QuASH: ``class MyMap(QuashIndexMixin, VLMap)``.

    Set ``self.quash`` (a ``Quash``, a config dict or a YAML path) before querying.
    """

    quash: Any = None

    def index_map(self, language_desc: str, with_init_cat: bool = True) -> np.ndarray:
        from ..engine.pipeline import Quash

        if not isinstance(self.quash, Quash):
            self.quash = resolve_quash(self.quash, self)
        return index_map(self, language_desc, with_init_cat, quash=self.quash)
