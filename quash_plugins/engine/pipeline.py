"""The QuASH pipeline: read the map, expand, encode, fit; then the map side; then results.

:class:`Quash` holds the configuration and the text side of a query: :meth:`Quash.read_map`
reads the map, :meth:`Quash._prepare` expands every query, embeds the query sets in one
encoder call and fits one classifier per query. The map side (the classification pass,
the finish, the refinement pass and the presence check) is
:mod:`quash_plugins.engine.answer`; :meth:`Quash._classify` picks where a pass runs.
:meth:`Quash.query_many` then groups instances and builds the
:class:`~quash_plugins.core.types.QueryResult` objects.

Examples
--------
>>> import numpy as np
>>> from quash_plugins import Quash, LatentMap, registry
>>> from quash_plugins.encoders import TableEncoder
>>> enc = TableEncoder(table={"chair": [1, 0, 0], "other": [0, 1, 0],
...                           "background": [0, 0, 1], "nothing": [0, 1, 1]})
>>> q = Quash(enc, classifier=registry.create("classifiers", "contrast"))
>>> m = LatentMap(np.array([[1, .1, 0], [0, 1, .2]], dtype=np.float32))
>>> q.query(m, "chair").mask.tolist()
[True, False]
"""

from __future__ import annotations

import logging
import time
import weakref
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from sklearn.base import clone

from ..core import registry
from ..core.config import (
    DEFAULT_CLASSIFIER,
    DEFAULT_HEURISTIC,
    PluginSpec,
    QuashConfig,
    check_device,
)
from ..core.errors import ConfigError, QuashError
from ..core.interfaces import Encoder, ExpansionContext, Heuristic
from ..core.text import TextCache
from ..core.types import DEFAULT_NEGATIVES, LatentMap, QueryResult, QuerySet, check_query
from ._pipeline_config import (  # BACKENDS and the _ names: as they were here
    BACKENDS,  # noqa: F401
    _check_chunk_mb,
    _queryset_words,
    adapter_spec,
    check_backend,
    check_cache,
    check_prompt_templates,
    check_queryset,
    describe,
    instance_options,
    templates_provenance,
)
from ._pipeline_maps import _none_ref, check_adapter_section
from ._pipeline_maps import read_map as _read_map
from ._pipeline_results import query_results
from ._pipeline_text import prepare
from .answer import Pending, answer
from .build import plugin_argument
from .classify import classify_local
from .map_cache import MapCache
from .map_fit import check_encoder_fits, warn_if_empty
from .training import training_sets

log = logging.getLogger(__name__)

#: From this many queries in one call, the text side shows progress.
PROGRESS_QUERIES = 20


class Quash:
    """Answer text queries against latent-semantic maps.

    Parameters
    ----------
    encoder
        Text encoder matching the map's embedding space.
    heuristic
        Expands a query into positives and negatives; default ``none``.
    classifier
        Unfitted scikit-learn estimator; cloned and fitted per query. Default
        ``nearest-sample`` (k=2), chosen by the quality benchmark; the paper's is ``svm-rbf``.

        Each of the three is a plugin object, or what a config gives: a registered name
        (``"svm-rbf"``), ``{"name": ..., **params}`` or a ``PluginSpec``, built through
        the registry. Anything else is refused here, naming the argument.
    negatives
        Generic negatives always added to the antonyms.
    threshold
        Items with ``score > threshold`` match.
    prompt_templates
        ``{"mode": "mean"|"all", "templates": "default"|"vlmaps"|"vlmaps-or-default"|list|
        path, "normalize": bool}`` or None (:func:`quash_plugins.core.text.resolve_templates`;
        :attr:`templates_source` says where the list came from). ``normalize: false``
        keeps the template mean as it is (VLMaps' rule); see
        :func:`quash_plugins.engine.training.training_set`.
    map_negatives
        Options for map-mined negatives (the ``map-negatives`` heuristic wraps
        ``heuristic``), or None.
    refine
        Options for transductive refinement (``quash_plugins.engine.refine.RefineOptions``):
        re-fit on the map's own confident items and classify again. None turns it off.
    presence
        Options of the presence check (``quash_plugins.engine.presence.PresenceOptions``):
        keep the matched components whose grown region the query set classifies as the
        query; none kept means the object is absent (an empty mask). None turns it off.
    adapter
        The map adapter of :meth:`read_map`: a registered name (default ``"auto"``),
        ``{"name": ..., **options}`` as a config's ``adapter:`` section (its options
        apply when that adapter reads a map) or a ``PluginSpec``.
    instances
        Options for instance grouping (True for defaults), or None/False to skip it.
    cache
        A text-embedding cache (anything with ``lookup`` and ``store``, e.g.
        :class:`quash_plugins.engine.TextEmbeddingCache`), or None. :meth:`from_config`
        opens the default on-disk cache when the config says ``cache: true``.
    chunk_mb
        Working-set budget of the classification pass.
    backend
        ``"numpy"`` (in-process chunks) or ``"dask"``.
    client
        A ``dask.distributed.Client`` for the dask backend.
    device
        Where the in-process classification pass runs: ``"cuda"`` (or ``"cuda:N"``) on
        the GPU, with the map uploaded once and kept there; ``"auto"`` on a CUDA GPU
        when one is visible, else the CPU; ``"cpu"`` (or ``"mps"``, which only the text
        encoder uses) on the CPU. Anything else is refused.
    """

    def __init__(
        self,
        encoder: Encoder,
        heuristic: Heuristic | None = None,
        classifier: Any = None,
        *,
        negatives: Sequence[str] = DEFAULT_NEGATIVES,
        threshold: float = 0.0,
        prompt_templates: dict[str, Any] | None = None,
        map_negatives: dict[str, Any] | None = None,
        refine: dict[str, Any] | None = None,
        presence: dict[str, Any] | None = None,
        adapter: str | Mapping[str, Any] | PluginSpec = "auto",
        instances: dict[str, Any] | bool | None = True,
        seed: int = 0,
        cache: TextCache | None = None,
        chunk_mb: float = 256.0,
        name: str = "quash",
        backend: str = "numpy",
        client: Any = None,
        device: str = "auto",
    ) -> None:
        self.device = check_device(device, "Quash: 'device'")
        self.encoder = plugin_argument("encoders", "encoder", encoder, self.device)
        self.heuristic = plugin_argument(
            "heuristics",
            "heuristic",
            DEFAULT_HEURISTIC if heuristic is None else heuristic,
            self.device,
        )
        self.classifier = plugin_argument(
            "classifiers",
            "classifier",
            DEFAULT_CLASSIFIER if classifier is None else classifier,
            self.device,
        )
        self.negatives = list(negatives)
        self.threshold = float(threshold)
        if prompt_templates is None:
            # A heuristic may ask for templates (the `templates` heuristic); config wins.
            prompt_templates = getattr(self.heuristic, "prompt_templates", None)
        self.prompt_templates = prompt_templates
        #: Where the prompt templates came from, in words (None without templates).
        self._templates, self.templates_source = check_prompt_templates(prompt_templates)
        self.map_negatives = map_negatives
        if map_negatives is not None:
            self.heuristic = registry.create(
                "heuristics", "map-negatives", base=self.heuristic, **dict(map_negatives)
            )
        self.refine = None
        if refine is not None:
            from .refine import RefineOptions

            self.refine = RefineOptions.parse(dict(refine))
            self._refine_template = self.refine.build_classifier()
        self.presence = None
        if presence is not None:
            from .presence import PresenceOptions, TopologyCache

            self.presence = PresenceOptions.parse(dict(presence))
            self._topology = TopologyCache()
        self.adapter = adapter_spec(adapter)
        self.instances = instance_options(instances)
        self.seed = seed
        self.cache = check_cache(cache)
        self.chunk_mb = _check_chunk_mb(chunk_mb)
        self.name = name
        #: The config file this pipeline was built from (set by :meth:`from_config`).
        self.config_source: str | None = None
        #: The arguments :meth:`from_config` was given over the file's (``adapter=``...):
        #: an error about one of them names the argument, not the file.
        self.config_overrides: frozenset[str] = frozenset()
        check_backend(backend, client)
        self.backend = backend
        self.client = client
        self._maps = MapCache()  # the maps read_map has read
        self._querysets: dict[tuple[str, int], tuple[Any, QuerySet]] = {}

    def __repr__(self) -> str:
        """One line: the config's name and the plugins and stages that answer a query
        (``refine`` names the re-fitted classifier; ``presence`` is on or off)."""
        return describe(self)

    # ------------------------------------------------------------------ building
    @classmethod
    def from_config(
        cls, config: str | Path | dict[str, Any] | QuashConfig, **overrides: Any
    ) -> Quash:
        """Build from a :class:`QuashConfig`, a dict or a YAML file.

        ``overrides`` replace constructor arguments (e.g. ``cache=None``, ``backend="dask"``).
        See :func:`quash_plugins.engine.build.build_quash`.
        """
        from .build import build_quash

        return build_quash(config, cls, **overrides)

    # ------------------------------------------------------------------ maps
    #: How many maps :meth:`read_map` keeps for reuse (the least recently used go first).
    keep_maps: int = 4

    def read_map(self, source: Any, adapter: str | None = None, **options: Any) -> LatentMap:
        """Read a map, reusing the one read before while its source is unchanged.

        A file is read again when its modification time or size changed (a map that a
        mapping process keeps rewriting); a live object (a ``VLMap``) when the arrays it
        holds were replaced or resized, or when the object is gone. The same options are
        required. At most :attr:`keep_maps` maps are kept; :meth:`forget_maps` drops them.

        A live object that the config's adapter does not recognise (a ``VLMap`` given
        to a config written for its files, ``adapter: {name: vlmaps}``) is read by the
        adapter that does (``vlmaps-live``), with ``options`` only: the config's
        ``adapter:`` options that disagree with the object are logged as a warning.
        """
        return _read_map(self, source, adapter, options)

    def _check_adapter_section(self, name: str) -> None:
        """Build adapter ``name`` with the config's own ``adapter:`` options, so that a bad
        one is reported as the config's (``q.yaml: adapter: ...``), not the command's."""
        check_adapter_section(self.adapter, name, self.config_source, self.config_overrides)

    def _source_of(self, section: str) -> str | None:
        """The config file a section came from; None when :meth:`from_config` was given it
        as an argument (the file's section was not used) or there is no file."""
        return None if section in self.config_overrides else self.config_source

    def forget_maps(self) -> None:
        """Drop the maps kept by :meth:`read_map` and the query sets built for them."""
        self._maps.clear()
        self._querysets.clear()

    def check_dimension(self, lmap: LatentMap) -> None:
        """Fail up front when the encoder's dimension differs from the map's; warn (once
        per map and encoder) when the map records that another encoder built it
        (:func:`~quash_plugins.engine.map_fit.check_encoder_fits`)."""
        check_encoder_fits(self.encoder, lmap, self._source_of("encoder"))

    # ------------------------------------------------------------------ steps
    def context(self, lmap: LatentMap | None = None, cache: Any = None) -> ExpansionContext:
        return ExpansionContext(
            encoder=self.encoder,
            label_names=list(lmap.label_names) if lmap is not None and lmap.label_names else None,
            map=lmap,
            seed=self.seed,
            negatives=tuple(self.negatives),
            extra={"cache": cache if cache is not None else self.cache},
        )

    def expand(self, text: str, lmap: LatentMap | None = None, *, cache: Any = None) -> QuerySet:
        """Expand ``text`` into a query set, adding the generic negatives.

        ``cache`` replaces :attr:`cache` for the heuristic's own text embeddings.
        """
        text = check_query(text)
        key = (text, id(lmap) if lmap is not None else 0)
        cached = self._querysets.get(key)
        if cached is not None and cached[0]() is lmap:
            return cached[1]
        qs = self.heuristic.expand(text, self.context(lmap, cache))
        qs = check_queryset(qs, self.heuristic, text, self.negatives)
        if self.prompt_templates is not None:
            qs.provenance["prompt_templates"] = templates_provenance(
                self.prompt_templates, self._templates, self.templates_source
            )
        if log.isEnabledFor(logging.DEBUG):  # -v: what the heuristic made of the query
            log.debug("query set for %r: %s", text, _queryset_words(qs))
        # A weak reference to the map guards against a new map reusing a freed one's id.
        self._querysets[key] = (weakref.ref(lmap) if lmap is not None else _none_ref, qs)
        return qs

    def training_set(self, qs: QuerySet) -> tuple[np.ndarray, np.ndarray, list[str]]:
        return self.training_sets([qs])[0]

    def fit(self, qs: QuerySet) -> Any:
        """Clone the classifier template and fit it on the query set's embeddings."""
        X, y, _ = self.training_set(qs)
        clf = clone(self.classifier)
        return clf.fit(X, y)

    # ------------------------------------------------------------------ queries
    def query(self, source: Any, text: str, **read_options: Any) -> QueryResult:
        """Answer one query. ``source`` is a path, a live map object or a LatentMap."""
        return self.query_many(source, [text], **read_options)[0]

    @property
    def passes(self) -> int:
        """Passes over the map per :meth:`query_many` call: 2 with ``refine``, else 1.

        ``progress(n)`` of :meth:`query_many` is advanced by ``lmap.n`` items per pass.
        """
        return 1 if self.refine is None else 2

    def query_many(
        self, source: Any, texts: Sequence[str], progress: Any = None, **read_options: Any
    ) -> list[QueryResult]:
        """Answer several queries with one pass over the map's embeddings (two with
        ``refine``), shared by all of them.

        Each distinct query is expanded once; the strings of all query sets are embedded
        in one encoder call (each distinct string once); one classifier is fitted per
        query; one pass over the map scores them all. ``progress(n)`` is told of map rows
        as they are classified: it adds up to ``lmap.n * self.passes``. From
        :data:`PROGRESS_QUERIES` queries the text side shows its own progress.

        In each result's timings, ``read``, ``encode`` and ``classify`` are the query's
        equal share of work done once for all the queries of the call, and
        ``reclassify`` its share of the refinement's pass (shared by the queries it
        refined); the other stages, ``refine`` (its re-fit) included, are its own.
        """
        if isinstance(texts, str):
            texts = [texts]
        texts = [check_query(t) for t in texts]
        if not texts:
            raise QuashError("No query given.")
        t0 = time.perf_counter()
        lmap = self.read_map(source, **read_options)
        t_read = time.perf_counter() - t0
        self.check_dimension(lmap)
        warn_if_empty(lmap)
        pending = self._prepare(lmap, texts, t_read)
        self._answer(lmap, pending, progress)
        return query_results(self, lmap, pending)

    def _prepare(self, lmap: LatentMap, texts: list[str], t_read: float) -> list[Pending]:
        """The text side of every query: expand each (once), embed the strings of all
        query sets in one encoder call, fit one classifier per query."""
        many = len(texts) >= PROGRESS_QUERIES  # read here: tests set it on this module
        return prepare(self, lmap, texts, t_read, many)

    def training_sets(
        self, querysets: Sequence[QuerySet], progress: Any = None, cache: Any = None
    ) -> list[tuple[np.ndarray, np.ndarray, list[str]]]:
        """:meth:`training_set` for many query sets, with one encoder call for all."""
        opts = self.prompt_templates or {}
        return training_sets(
            self.encoder,
            querysets,
            cache if cache is not None else self.cache,
            self._templates,
            opts.get("mode", "mean"),
            bool(opts.get("normalize", True)),
            progress=progress,
        )

    # ------------------------------------------------------------------ the map side
    # The steps after the text side live in quash_plugins.engine.answer; _answer is their
    # name on the pipeline (LazyQuery calls it). _classify, the one place a pass is
    # dispatched to its executor, stays here.
    def _answer(
        self, lmap: LatentMap, pending: list[Pending], progress: Any = None, client: Any = None
    ) -> np.ndarray:
        """The map side of :meth:`query_many` for ``pending``, in place: the first pass,
        the finish, the refinement pass and the presence check; returns the
        ``observed`` mask. See :func:`quash_plugins.engine.answer.answer`."""
        return answer(self, lmap, pending, progress, client)

    def _classify(
        self, lmap: LatentMap, classifiers: list[Any], progress: Any, client: Any = None
    ) -> tuple[list[np.ndarray], np.ndarray]:
        """One pass of ``classifiers`` over ``lmap``: on Dask with ``backend: dask`` or a
        ``client`` given here (it replaces :attr:`client`), else in this process."""
        chunk_bytes = int(self.chunk_mb * 2**20)
        if self.backend == "dask" or client is not None:
            from .dask_executor import classify_dask

            client = client if client is not None else self.client
            return classify_dask(
                lmap, classifiers, chunk_bytes=chunk_bytes, client=client, progress=progress
            )
        if self.backend not in ("numpy", "local", None):
            raise ConfigError(f"Unknown backend {self.backend!r}. Known: numpy, dask.")
        from .device import pass_device

        device = pass_device(self.device)
        if device is not None:  # the map is uploaded once and kept while it lives
            from .device import classify_on_device, device_map

            dmap = device_map(lmap, device, chunk_bytes=min(chunk_bytes, 64 * 2**20))
            return classify_on_device(dmap, classifiers, progress)
        return classify_local(lmap, classifiers, chunk_bytes, progress)

    def query_many_lazy(self, source: Any, texts: Sequence[str], **read_options: Any) -> Any:
        """Like :meth:`query_many`, but masks and scores stay dask arrays until written.

        Returns a :class:`quash_plugins.engine.LazyQuery`; runs on :attr:`client` when
        set. Needs the ``[dask]`` extra. ``.to_zarr(path)`` writes :meth:`query_many`'s
        masks and scores, ``refine`` and ``presence`` applied (the queries answered in
        groups, ``(N,)`` vectors held per query, never the embeddings); ``.masks`` and
        ``.scores`` are the first pass only, and warn so when the config has either step
        (see :func:`quash_plugins.engine.lazy_query.query_lazy`).
        """
        from .lazy_query import query_lazy

        return query_lazy(self, source, texts, self.client, **read_options)
