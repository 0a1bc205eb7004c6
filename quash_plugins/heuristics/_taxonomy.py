"""``taxonomy`` heuristic: the paper's "ground truth" from a label -> sub-classes file."""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from ..core.errors import ConfigError, HeuristicError, closest
from ..core.interfaces import ExpansionContext, Heuristic
from ..core.text import head_index
from ..core.types import QuerySet, taxonomy_path_beside
from ._data import read_mapping

log = logging.getLogger(__name__)


#: The keys of a query file (present, absent and evaluation.queries.QUERY_FILE_INFO, what
#: make-scene adds): a mapping of only these is a query file given for a taxonomy.
_QUERY_FILE_KEYS = frozenset(
    {"present", "absent", "kind", "room_types", "options", "class_table_sha256"}
    | {"absent_lookalikes"}
)


def load_taxonomy(spec: str | dict | None, key: str = "file") -> dict[str, list[str]]:
    """``{label: [sub-class, ...]}`` from a YAML file or a dict; ``null`` means no sub-classes.

    ``key``: the heuristic's option that named the file, said when it is missing.
    """
    option = (
        f"The heuristic's {key!r} option names it: give a YAML file of {{label: [sub-class, "
        "...]} (quash make-scene writes one, SCENE.taxonomy.yaml), or leave it out to use "
        "the map's label names."
    )
    data = read_mapping(spec, None, "taxonomy", form=("label", "sub-class"), option=option)
    where = spec if isinstance(spec, str) else "the taxonomy"
    if data and set(data) <= _QUERY_FILE_KEYS and ({"present", "absent"} & set(data)):
        raise ConfigError(
            f"{where}: this is a query file ({{present: ..., absent: [...]}}, as make-scene's "
            "SCENE.queries.yaml), not a taxonomy ({label: [sub-class, ...]}, make-scene's "
            "SCENE.taxonomy.yaml)."
        )
    out: dict[str, list[str]] = {}
    for label, subs in data.items():
        if subs is None:
            subs = []
        if not isinstance(subs, list):
            raise ConfigError(
                f"{where}: label {label!r} must map to a list of sub-classes (or be empty)."
            )
        key = " ".join(str(label).split())
        out[key] = list(dict.fromkeys(" ".join(str(s).split()) for s in subs if str(s).strip()))
    if not out:
        raise ConfigError(f"{where}: the taxonomy has no labels.")
    return out


_BESIDE: dict[tuple[str, int], dict[str, list[str]]] = {}


def taxonomy_beside(lmap: Any) -> tuple[str, dict[str, list[str]]] | None:
    """``(path, taxonomy)`` of ``MAP.taxonomy.yaml`` next to the map's file, if there is one.

    ``quash make-scene OUT.npz`` writes ``OUT.taxonomy.yaml``; a map read from ``OUT.npz``
    finds it here, so a config without ``file`` gets the scene's sub-classes too. A file
    that is not a taxonomy is ignored (with a log line).
    """

    path = (getattr(lmap, "source", None) or {}).get("path") if lmap is not None else None
    if not path:
        return None
    cand = taxonomy_path_beside(path)
    if cand is None or not cand.is_file():
        return None
    try:
        key = (str(cand.resolve()), cand.stat().st_mtime_ns)
        if key not in _BESIDE:
            if len(_BESIDE) > 16:
                _BESIDE.clear()
            _BESIDE[key] = load_taxonomy(str(cand))
    except (OSError, ConfigError) as exc:
        log.info("ignoring %s beside the map: %s", cand, exc)
        return None
    return str(cand), _BESIDE[key]


def taxonomy_missing(lmap: Any) -> tuple[str, bool]:
    """Where the map's ``MAP.taxonomy.yaml`` was looked for, when none was found, and
    whether a taxonomy lies where it is not read: ``("", False)`` for a map without a
    path. A folder map's taxonomy sits beside the folder its adapter read
    (ConceptFusion's ``saved-map/pointclouds.taxonomy.yaml``), so one beside the folder
    above it (``saved-map.taxonomy.yaml``, beside the folder a user passes) is named."""
    from pathlib import Path

    path = (getattr(lmap, "source", None) or {}).get("path") if lmap is not None else None
    cand = taxonomy_path_beside(path) if path else None
    if cand is None:
        return "", False
    above = taxonomy_path_beside(Path(str(path)).parent) if Path(str(path)).is_dir() else None
    if above is not None and above.is_file():
        return (
            f"looked for {cand}, not found; {above}, beside the folder above the map, "
            f"is not read: move it to {cand}"
        ), True
    return f"looked for {cand}, not found", False


def _no_file_hint(lmap: Any) -> str:
    """For a map read from an object in memory (a live VLMap), no file: where to say
    which file it was loaded from, so that the taxonomy beside that file is read."""
    source = (getattr(lmap, "source", None) or {}) if lmap is not None else {}
    if not source.get("live") or source.get("path"):
        return ""
    return (
        f" This map is a live {source['live']} object with no file, so no taxonomy beside "
        "a file is looked for: set vlmap.map_save_path to the file it was loaded from, or "
        "give the vlmaps-live adapter's path option (docs/vlmaps.md)."
    )


class TaxonomyHeuristic(Heuristic):
    """Synonyms from the query label's sub-classes, antonyms from the other labels'.

    Parameters
    ----------
    file
        YAML ``{label: [sub-class, ...]}`` (e.g. Matterport3D's 40 labels with their
        1,659 fine classes). Without it, the label list is the map's label names, with
        sub-classes from ``MAP.taxonomy.yaml`` when that file sits next to the map's file
        (``quash make-scene`` writes it; :func:`taxonomy_beside`).
    taxonomy
        The same mapping given in memory.
    n_synonyms
        Up to this many sub-classes of the query's label, sampled (the paper: 20).
    n_antonyms
        Up to this many sub-classes of the other labels, sampled (the paper: 100), or
        ``"all"``: every other label with all its sub-classes, recorded label by label in
        ``provenance["negative_groups"]`` (the presence check scores each label as one
        competitor).
    include_other_labels
        Also count the other labels' own names as antonym candidates.
    resolve
        Resolve a query that is not a label: a listed sub-class or a near match of a
        label or sub-class resolves to its label, anything else to the label of the
        nearest label or sub-class by cosine similarity of the encoder's text embeddings
        (:meth:`resolve_query`; reported in provenance, ``quash expand`` and the log). When
        False, a query that is neither a label nor a (near) sub-class is an error.
    min_similarity
        A query whose nearest label has a lower cosine is not forced onto that label: it
        stays its own positive and every label's sub-classes are antonym candidates, so
        an object the taxonomy does not know ("an elephant") can come back empty.
    unlisted
        Off by default (null). ``"vocabulary"`` (the shipped vocabulary of 1,144 names), a
        list, or a file (one name a line, or a YAML list): names of objects that the list
        may not hold. A query that is one of them (after :func:`normalise_name`), and
        shares its head noun with no label or sub-class, names an object of its own: it is
        not resolved by embedding ("fireplace" does not become "stove" on a list without a
        fireplace), so an object missing from the list can come back empty. The price: on
        a list of bare label names, near-synonyms and kinds that only the embedding links
        to their label ("couch" -> sofa, "shrub" -> plant) are not resolved either
        (docs/benchmarks.md measures both).
    """

    name = "taxonomy"

    def __init__(
        self,
        file: str | None = None,
        taxonomy: dict[str, Any] | None = None,
        n_synonyms: int = 20,
        n_antonyms: int | str = 100,
        include_other_labels: bool = True,
        resolve: bool = True,
        min_similarity: float = 0.5,
        unlisted: str | list[str] | None = None,
    ) -> None:
        if file is not None and taxonomy is not None:
            raise ConfigError("Heuristic 'taxonomy' takes 'file' or 'taxonomy', not both.")
        self.unlisted = unlisted
        self._unlisted = _unlisted_names(unlisted)
        self.file = file
        self.taxonomy = taxonomy
        self.n_synonyms = int(n_synonyms)
        if isinstance(n_antonyms, str) and n_antonyms != "all":
            raise ConfigError(
                f"Heuristic 'taxonomy': n_antonyms must be a number or 'all'; got {n_antonyms!r}."
            )
        # None: "all", every other label with all its sub-classes, recorded label by label
        self.n_antonyms = None if n_antonyms == "all" else int(n_antonyms)
        self.include_other_labels = bool(include_other_labels)
        self.resolve = bool(resolve)
        self.min_similarity = float(min_similarity)
        if self.n_synonyms < 0 or (self.n_antonyms is not None and self.n_antonyms < 0):
            raise ConfigError("Heuristic 'taxonomy': n_synonyms and n_antonyms must be >= 0.")
        spec = file if file is not None else taxonomy
        key = "file" if file is not None else "taxonomy"
        self._tax = load_taxonomy(spec, key) if spec is not None else None

    def _labels(self, context: ExpansionContext) -> dict[str, list[str]]:
        if self._tax is not None:
            return self._tax
        beside = taxonomy_beside(context.map)
        if context.label_names or beside:
            out = {k: list(v) for k, v in (beside[1] if beside else {}).items()}
            for name in context.label_names or []:
                key = " ".join(str(name).split())
                if key and key.lower() not in {k.lower() for k in out}:
                    out[key] = []
            return out
        missing = taxonomy_missing(context.map)[0]
        raise HeuristicError(
            f"Heuristic {self.name!r} has no taxonomy (no label list): give 'file' "
            "({label: [sub-class, ...]}) or query a map that has label_names (or a "
            "MAP.taxonomy.yaml beside its file); quash expand reads that map with --map MAP."
            + (f" This map has no label names; {missing}." if missing else "")
            + _no_file_hint(context.map)
        )

    def _labels_source(self, context: ExpansionContext | None) -> str:
        """Where the label list came from, for the provenance."""
        if self._tax is not None:
            return self.file or "the taxonomy given in memory"
        beside = taxonomy_beside(context.map if context is not None else None)
        names = "the map's label names" if context is not None and context.label_names else ""
        if beside:
            return f"{names} + {beside[0]}" if names else beside[0]
        return names or "none"

    def resolve_label(
        self, query: str, context: ExpansionContext
    ) -> tuple[str | None, float | None]:
        """The taxonomy label for ``query`` and, when resolved by embedding, its cosine.

        The label is None when nothing is within ``min_similarity``. See
        :meth:`resolve_query` for the whole record.
        """
        r = self.resolve_query(query, context)
        return r["to"], r.get("cosine")

    def resolve_query(self, query: str, context: ExpansionContext) -> dict[str, Any]:
        """Resolve ``query`` to a label; the first rule that applies wins.

        1. ``label``: the query is a label (case-insensitive).
        2. ``subclass``: the query is a listed sub-class ("bunk bed" -> bed): the first
           label that lists it, in file order.
        3. ``near-label`` / ``near-subclass``: equal after :func:`normalise_name` (case,
           hyphens, a leading article, a plural head noun): "Bunk-beds" -> "bunk bed".
        4. ``unlisted`` (only with that option): the query is an object name of
           ``unlisted`` whose head noun no label or sub-class has ("fireplace" on a list
           without one): it stays its own concept (label None).
        5. ``embedding``: the nearest of all labels *and* sub-classes by the encoder's
           cosine, when at least ``min_similarity`` ("somewhere to sleep" -> bed).
        6. ``none``: the query stays its own concept (label None).

        Returns ``{"from", "to", "how", "via", "cosine"}``; ``via`` is the name matched.
        Rule 6 also records ``nearest`` (the label of ``via``) and ``min_similarity``, so
        an empty answer can say which label the query was nearest to; rules 5 and 6
        record the best other label as ``next`` with its ``next_cosine`` (a near tie).
        """
        tax = self._labels(context)
        q = " ".join(query.split())
        low = q.lower()
        for label in tax:
            if label.lower() == low:
                return {"from": query, "to": label, "how": "label", "via": label}
        for label, subs in tax.items():
            for sub in subs:
                if sub.lower() == low:
                    return {"from": query, "to": label, "how": "subclass", "via": sub}
        nq = normalise_name(q)
        for label in tax:
            if normalise_name(label) == nq:
                return {"from": query, "to": label, "how": "near-label", "via": label}
        for label, subs in tax.items():
            for sub in subs:
                if normalise_name(sub) == nq:
                    return {"from": query, "to": label, "how": "near-subclass", "via": sub}
        if self.resolve and nq in self._unlisted:
            heads = {
                head_noun(normalise_name(n)) for lab, subs in tax.items() for n in (lab, *subs)
            }
            if head_noun(nq) not in heads:
                log.info(
                    "taxonomy: query %r names an object that is not in the label list, so it "
                    "is kept as its own concept (not resolved to the nearest label)",
                    query,
                )
                return {"from": query, "to": None, "how": "unlisted", "via": nq}
        where = self.file or "the taxonomy"
        if not self.resolve or context.encoder is None:
            guess = closest(query, tax)
            hint = f" Did you mean {guess!r}?" if guess else ""
            why = "resolve is off" if not self.resolve else "no encoder to resolve it"
            raise HeuristicError(
                f"Query {query!r} is not a label or sub-class of {where} ({why}).{hint} "
                f"Labels: {', '.join(list(tax)[:30])}{' ...' if len(tax) > 30 else ''}."
            )
        from ..core.text import encode_texts

        names, owner = [], []
        for label, subs in tax.items():
            for name in (label, *subs):
                names.append(name)
                owner.append(label)
        cache = context.extra.get("cache")
        E = encode_texts(context.encoder, names, cache)
        v = encode_texts(context.encoder, [q], cache)[0]
        sims = E @ v
        best = int(np.argmax(sims))
        cos = round(float(sims[best]), 4)
        # the best other label, so that a near tie ("fabric that covers the window":
        # window 0.647, curtain 0.643) can be seen in provenance and quash expand
        others = [i for i in range(len(names)) if owner[i] != owner[best]]
        second = max(others, key=lambda i: float(sims[i])) if others else None
        runner = (
            {"next": owner[second], "next_cosine": round(float(sims[second]), 4)}
            if second is not None
            else {}
        )
        if float(sims[best]) < self.min_similarity:
            log.info(
                "taxonomy: query %r matches no label; nearest name %r (label %r, cosine "
                "%.3f) is below min_similarity %.2f, so it is kept as its own concept",
                query,
                names[best],
                owner[best],
                cos,
                self.min_similarity,
            )
            return {
                "from": query,
                "to": None,
                "how": "none",
                "via": names[best],
                "nearest": owner[best],
                "cosine": cos,
                "min_similarity": self.min_similarity,
                **runner,
            }
        log.info(
            "taxonomy: query %r resolved to label %r through %r (cosine %.3f%s)",
            query,
            owner[best],
            names[best],
            cos,
            f"; next label {runner['next']!r}, {runner['next_cosine']:.3f}" if runner else "",
        )
        return {
            "from": query,
            "to": owner[best],
            "how": "embedding",
            "via": names[best],
            "cosine": cos,
            **runner,
        }

    def expand(self, query: str, context: ExpansionContext | None = None) -> QuerySet:
        ctx = context or ExpansionContext()
        tax = self._labels(ctx)
        res = self.resolve_query(query, ctx)
        label = res["to"]
        rng = ctx.rng(f"taxonomy|{label if label is not None else query}")
        own = tax[label] if label is not None else []
        syn = _sample(own, self.n_synonyms, rng)
        mine = {query.lower(), *(s.lower() for s in own)}
        if label is not None:
            mine.add(label.lower())
        pool: list[str] = []
        sizes: list[int] = []
        seen: set[str] = set()
        for other, subs in tax.items():
            if other == label:
                continue
            cands = ([other] if self.include_other_labels else []) + subs
            group = [c for c in dict.fromkeys(cands) if c.lower() not in mine and c not in seen]
            seen.update(group)
            pool.extend(group)
            sizes.append(len(group))
        ant = pool if self.n_antonyms is None else _sample(pool, self.n_antonyms, rng)
        extra: dict[str, Any] = {"label": label, "labels_from": self._labels_source(ctx)}
        if self.n_antonyms is None:
            # every other label's names, label by label: the presence check scores each
            # label as one competitor
            extra["negative_groups"] = [n for n in sizes if n]
        if res["how"] != "label":
            extra["resolved"] = res
        positives = [query, label, *syn] if label is not None else [query]
        return QuerySet(query, positives, ant, self.provenance(context, **extra))

    def params(self) -> dict[str, Any]:
        return {
            "file": self.file,
            "labels": len(self._tax) if self._tax is not None else None,
            "n_synonyms": self.n_synonyms,
            "n_antonyms": "all" if self.n_antonyms is None else self.n_antonyms,
            "include_other_labels": self.include_other_labels,
            "resolve": self.resolve,
            "min_similarity": self.min_similarity,
            "unlisted": unlisted_param(self.unlisted),
        }


def _unlisted_names(spec: str | list[str] | None) -> frozenset[str]:
    """The normalised names of ``unlisted`` (empty when off)."""
    if spec is None:
        return frozenset()
    from ._vocabulary import VOCABULARY_FIX, load_vocabulary

    option = (
        f"The heuristic's 'unlisted' option names it: {VOCABULARY_FIX}, 'vocabulary' for "
        "the shipped vocabulary, or leave it out to turn it off."
    )
    names = load_vocabulary(None if spec == "vocabulary" else spec, option)
    return frozenset(normalise_name(n) for n in names)


def unlisted_param(spec: str | list[str] | None) -> Any:
    """``unlisted`` as a parameter record: a list given in memory by its length."""
    return f"{len(spec)} names" if isinstance(spec, (list, tuple)) else spec


_ARTICLES = ("a ", "an ", "the ", "some ")

# Plurals that dropping "s" or "es" gets wrong ("shelves" is not "shelve"). "-ves" stays
# "-ve" otherwise ("stoves", "gloves", "sleeves"), and "-oes" stays "-oe" ("shoes").
_IRREGULAR = {
    "shelves": "shelf", "knives": "knife", "leaves": "leaf", "loaves": "loaf",
    "halves": "half", "scarves": "scarf", "wolves": "wolf", "calves": "calf",
    "hooves": "hoof", "thieves": "thief", "wives": "wife", "lives": "life",
    "potatoes": "potato", "tomatoes": "tomato", "mangoes": "mango", "echoes": "echo",
    "heroes": "hero", "volcanoes": "volcano", "dominoes": "domino", "mosquitoes": "mosquito",
    "mice": "mouse", "geese": "goose", "feet": "foot", "teeth": "tooth",
    "children": "child", "people": "person", "men": "man", "women": "woman",
    "cacti": "cactus", "fungi": "fungus",
}  # fmt: skip
# Endings of compounds that take the same plural ("bookshelves", "penknives", "housewives").
_IRREGULAR_ENDINGS = ("shelves", "knives", "wives")


def head_noun(name: str) -> str:
    """The head noun of a normalised name ("chest" of "chest of drawers", "bed" of "bunk bed").

    >>> head_noun("chest of drawers"), head_noun("bunk bed")
    ('chest', 'bed')
    """
    words = name.split()
    return words[head_index(words)] if words else ""


def normalise_name(text: str) -> str:
    """Lower case, hyphens and underscores as spaces, no leading article, singular head.

    The head is the word before "of" ("chests of drawers"), else the last word.

    >>> normalise_name("A Bunk-Beds"), normalise_name("benches"), normalise_name("glass")
    ('bunk bed', 'bench', 'glass')
    >>> normalise_name("Chests of Drawers"), normalise_name("pile of clothes")
    ('chest of drawers', 'pile of clothes')
    >>> normalise_name("bookshelves"), normalise_name("stoves"), normalise_name("potatoes")
    ('bookshelf', 'stove', 'potato')
    """
    t = " ".join(text.lower().replace("-", " ").replace("_", " ").split())
    for a in _ARTICLES:
        if t.startswith(a):
            t = t[len(a) :]
            break
    words = t.split()
    if words:
        head = head_index(words)
        w = words[head]
        ending = next((e for e in _IRREGULAR_ENDINGS if w.endswith(e)), None)
        if w in _IRREGULAR:
            w = _IRREGULAR[w]
        elif ending is not None:
            w = w[: -len(ending)] + _IRREGULAR[ending]
        elif len(w) > 4 and w.endswith("ies"):
            w = w[:-3] + "y"
        elif len(w) > 4 and w.endswith(("ches", "shes", "sses", "xes", "zes")):
            w = w[:-2]
        elif len(w) > 3 and w.endswith("s") and not w.endswith(("ss", "us", "is")):
            w = w[:-1]
        words[head] = w
    return " ".join(words)


def _sample(items: list[str], n: int, rng: np.random.Generator) -> list[str]:
    if len(items) <= n:
        return list(items)
    idx = rng.choice(len(items), size=n, replace=False)
    return [items[i] for i in sorted(idx.tolist())]


class LabelListHeuristic(TaxonomyHeuristic):
    """The fair peer's query set: the resolved label against every other label.

    What VLMaps with its category list and OpenScene's label argmax are given
    (``classifier: label-argmax``): positives ``[label]`` (the query itself when it
    resolves to no label), negatives every other label of the taxonomy (no sub-classes,
    no sampling). The query resolves exactly as the ``taxonomy`` heuristic resolves it
    (label, sub-class, near match, embedding), so a peer and QuASH given the same label
    list see the same resolution. Without ``file``, the map's label names are the list.

    Examples
    --------
    >>> h = LabelListHeuristic(taxonomy={"bed": ["bunk bed"], "sofa": ["futon"], "chair": []})
    >>> qs = h.expand("bunk beds")
    >>> qs.positives, qs.negatives
    (['bed'], ['sofa', 'chair'])
    """

    name = "label-list"

    def __init__(
        self,
        file: str | None = None,
        taxonomy: dict[str, Any] | None = None,
        resolve: bool = True,
        min_similarity: float = 0.5,
        unlisted: str | list[str] | None = None,
    ) -> None:
        super().__init__(
            file=file,
            taxonomy=taxonomy,
            n_synonyms=0,
            n_antonyms=0,
            resolve=resolve,
            min_similarity=min_similarity,
            unlisted=unlisted,
        )

    def expand(self, query: str, context: ExpansionContext | None = None) -> QuerySet:
        ctx = context or ExpansionContext()
        tax = self._labels(ctx)
        res = self.resolve_query(query, ctx)
        label = res["to"]
        positives = [label] if label is not None else [query]
        negatives = [other for other in tax if other != label]
        extra: dict[str, Any] = {"label": label, "labels_from": self._labels_source(ctx)}
        if res["how"] != "label":
            extra["resolved"] = res
        return QuerySet(query, positives, negatives, self.provenance(context, **extra))

    def params(self) -> dict[str, Any]:
        return {
            "file": self.file,
            "labels": len(self._tax) if self._tax is not None else None,
            "resolve": self.resolve,
            "min_similarity": self.min_similarity,
            "unlisted": unlisted_param(self.unlisted),
        }
