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
from ..core.errors import ConfigError, MapFormatError, QuashError
from ..core.interfaces import Encoder, ExpansionContext, Heuristic, plugin_name
from ..core.text import TextCache, encode_texts, resolve_templates
from ..core.types import DEFAULT_NEGATIVES, LatentMap, QueryResult, QuerySet, check_query
from .answer import Pending, answer, classifier_words
from .build import plugin_argument
from .classify import classify_local
from .map_cache import MapCache
from .map_fit import (
    check_encoder_fits,
    option_source,
    warn_if_empty,
    warn_unused_adapter_options,
)
from .training import CallCache, training_sets

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
        self._templates = None
        #: Where the prompt templates came from, in words (None without templates).
        self.templates_source: str | None = None
        if prompt_templates is not None:
            unknown = set(prompt_templates) - {"mode", "templates", "normalize"}
            if unknown:
                raise ConfigError(
                    f"prompt_templates does not accept {sorted(unknown)}; it takes mode, "
                    "templates and normalize."
                )
            if not isinstance(prompt_templates.get("normalize", True), bool):
                raise ConfigError("prompt_templates: normalize must be true or false.")
            resolved = resolve_templates(prompt_templates.get("templates", "default"))
            self._templates, self.templates_source = resolved
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
        if isinstance(adapter, Mapping) and isinstance(adapter.get("name"), str):
            # the config's form, {name: vlmaps, cs: 0.05}: its options apply to read_map
            adapter = PluginSpec(adapter["name"], {k: v for k, v in adapter.items() if k != "name"})
        self.adapter = adapter if isinstance(adapter, PluginSpec) else PluginSpec(str(adapter))
        if instances is True:
            instances = {}
        self.instances = dict(instances) if isinstance(instances, dict) else None
        self.seed = seed
        if cache is True or cache is False:
            if cache:
                raise ConfigError(
                    "Quash(cache=True): pass a cache object, e.g. "
                    "quash_plugins.engine.TextEmbeddingCache(), or build with "
                    "Quash.from_config (which opens the default cache for 'cache: true')."
                )
            cache = None
        self.cache = cache
        self.chunk_mb = _check_chunk_mb(chunk_mb)
        self.name = name
        #: The config file this pipeline was built from (set by :meth:`from_config`).
        self.config_source: str | None = None
        #: The arguments :meth:`from_config` was given over the file's (``adapter=``...):
        #: an error about one of them names the argument, not the file.
        self.config_overrides: frozenset[str] = frozenset()
        if backend not in BACKENDS:
            raise ConfigError(
                f"Unknown backend {backend!r}. Known: {', '.join(b for b in BACKENDS if b)}."
            )
        if isinstance(client, str):
            raise ConfigError(
                f"client={client!r}: pass a dask.distributed.Client, e.g. "
                f"Client({client!r}), not its address (quash --scheduler ADDRESS connects "
                "on the command line)."
            )
        self.backend = backend
        self.client = client
        self._maps = MapCache()  # the maps read_map has read
        self._querysets: dict[tuple[str, int], tuple[Any, QuerySet]] = {}

    def __repr__(self) -> str:
        """One line: the config's name and the plugins and stages that answer a query
        (``refine`` names the re-fitted classifier; ``presence`` is on or off)."""
        refine = self.refine.classifier if self.refine is not None else None
        if isinstance(refine, dict):
            refine = refine.get("name")
        parts = [
            f"name={self.name!r}",
            f"encoder={plugin_name(self.encoder)!r}",
            f"heuristic={plugin_name(self.heuristic)!r}",
            f"classifier={plugin_name(self.classifier)!r}",
            f"refine={str(refine) if refine is not None else None!r}",
            f"presence={'on' if self.presence is not None else 'off'!r}",
            f"backend={self.backend!r}",
            f"device={self.device!r}",
        ]
        return f"Quash({', '.join(parts)})"

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
        from ..core.maps import live_adapter, read_map, resolve_adapter

        if isinstance(source, LatentMap):
            return source
        name = adapter or self.adapter.name
        live = live_adapter(source, name) if adapter is None and name != "auto" else None
        if live is not None:
            lmap = self.read_map(source, live, **options)
            warn_unused_adapter_options(self.adapter, lmap, source, options)
            return lmap
        if name in (None, "auto"):
            # Resolve "auto" first, so the options the config gives for the adapter it
            # picks (or for "auto" itself) apply.
            source, name = resolve_adapter(source, name)
        configured = self.adapter.name in (name, "auto")
        opts = {**self.adapter.params, **options} if configured else options
        if configured and self.adapter.params:
            self._check_adapter_section(name)
        kept, token = self._maps.lookup(source, name, opts)
        if kept is not None:
            return kept
        try:
            lmap = read_map(source, name, **opts)
        except MapFormatError as exc:
            given = options if configured else None
            origin = (
                "the adapter= argument of Quash.from_config"
                if "adapter" in self.config_overrides
                else None
            )
            raise option_source(exc, self.adapter, self.config_source, given, origin) from None
        self._maps.store(token, lmap, self.keep_maps)
        # the query sets of maps that are gone go too (here, not on every expand)
        for k in [k for k, (r, _) in self._querysets.items() if k[1] and r() is None]:
            del self._querysets[k]
        return lmap

    def _check_adapter_section(self, name: str) -> None:
        """Build adapter ``name`` with the config's own ``adapter:`` options, so that a bad
        one is reported as the config's (``q.yaml: adapter: ...``), not the command's."""
        from ..core import registry
        from ..core.errors import ConfigError

        try:
            registry.create("adapters", name, **self.adapter.params)
        except ConfigError as exc:
            if "adapter" in self.config_overrides:
                raise ConfigError(f"Quash.from_config(adapter=...): {exc}") from None
            where = f"{self.config_source}: " if self.config_source else ""
            raise ConfigError(f"{where}adapter: {exc}") from None

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
        if not isinstance(qs, QuerySet):
            raise QuashError(
                f"Heuristic {plugin_name(self.heuristic)!r} returned "
                f"{type(qs).__name__}, not a QuerySet."
            )
        qs = qs.with_negatives(self.negatives)
        if not qs.negatives:
            raise QuashError(
                f"Query set for {text!r} has no negatives; configure 'negatives' or a heuristic "
                "that produces antonyms."
            )
        if self.prompt_templates is not None:
            qs.provenance["prompt_templates"] = {
                "mode": self.prompt_templates.get("mode", "mean"),
                "count": len(self._templates or []),
                "source": self.templates_source,
                "normalize": bool(self.prompt_templates.get("normalize", True)),
            }
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
        results = []
        for p in pending:
            instances = []
            if self.instances is not None:
                from .instances import find_instances

                t = time.perf_counter()
                instances = find_instances(lmap, p.mask, p.display, **self.instances)
                p.timings["instances"] = time.perf_counter() - t
            p.timings["total"] = sum(p.timings.values())
            results.append(
                QueryResult(
                    queryset=p.queryset,
                    mask=p.mask,
                    scores=p.raw,
                    display_scores=p.display,
                    threshold=self.threshold,
                    instances=instances,
                    timings=p.timings,
                    classifier=classifier_words(p),
                    config_name=self.name,
                    map_source=dict(lmap.source),
                    rejected=p.rejected,
                )
            )
        return results

    def _prepare(self, lmap: LatentMap, texts: list[str], t_read: float) -> list[Pending]:
        """The text side of every query: expand each (once), embed the strings of all
        query sets in one encoder call, fit one classifier per query."""
        from ..core.progress import progress

        many = len(texts) >= PROGRESS_QUERIES
        timings = [{"read": t_read / len(texts)} for _ in texts]
        call_cache = CallCache(self.cache)
        t = time.perf_counter()
        if len(texts) > 1:  # one encoder call for every query, for heuristics that embed it
            encode_texts(self.encoder, list(dict.fromkeys(texts)), call_cache)
        t_queries = (time.perf_counter() - t) / len(texts)
        querysets = []
        with progress(len(texts) if many else 0, f"expanding {len(texts)} queries") as advance:
            for text, tm in zip(texts, timings):
                t = time.perf_counter()
                querysets.append(self.expand(text, lmap, cache=call_cache))
                tm["expand"] = time.perf_counter() - t
                advance(1)
        t = time.perf_counter()
        with progress(len(texts) if many else 0, f"encoding {len(texts)} query sets") as advance:
            sets = self.training_sets(querysets, progress=advance, cache=call_cache)
        t_encode = (time.perf_counter() - t) / len(texts) + t_queries
        pending = []
        with progress(len(texts) if many else 0, f"fitting {len(texts)} classifiers") as advance:
            for qs, (X, y, _), tm in zip(querysets, sets, timings):
                tm["encode"] = t_encode
                t = time.perf_counter()
                clf = clone(self.classifier).fit(X, y)
                tm["fit"] = time.perf_counter() - t
                pending.append(Pending(qs, X, y, clf, tm))
                advance(1)
        return pending

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


#: The backends a Quash takes (None and "local": the in-memory pass, as "numpy").
BACKENDS = ("numpy", "local", "dask", None)


def _check_chunk_mb(value: Any) -> float:
    """``chunk_mb`` as a float, refused unless positive and finite (as a config's is)."""
    import math

    try:
        out = float(value)
    except (TypeError, ValueError):
        out = math.nan
    if not (math.isfinite(out) and out > 0):
        raise ConfigError(f"chunk_mb must be a positive, finite number of MiB; got {value!r}.")
    return out


def _queryset_words(qs: QuerySet, limit: int = 24) -> str:
    """``heuristic (source); N positives: a, b, ...; M negatives: ...``, each list cut at
    ``limit`` names (the log line of ``-v``)."""

    def head(words: Sequence[str]) -> str:
        shown = ", ".join(words[:limit])
        return shown + (f", ... and {len(words) - limit} more" if len(words) > limit else "")

    prov = qs.provenance or {}
    how = str(prov.get("heuristic", "?"))
    if prov.get("source"):  # llm: server or cache
        how += f" from {prov['source']}"
    return (
        f"{how}; {len(qs.positives)} positives: {head(qs.positives)}; "
        f"{len(qs.negatives)} negatives: {head(qs.negatives)}"
    )


def _none_ref() -> None:
    return None
