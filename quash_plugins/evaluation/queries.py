"""Query lists for evaluation: ``TEXT=LABEL`` items and query files.

``quash eval --queries "bunk bed=bed,chair"`` and ``--queries-file Q.yaml`` name each
query with its ground-truth label; :func:`parse_queries` and :func:`load_query_file`
read them into ``{query text: label}`` (and a list of absence queries).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ..core.errors import QuashError
from ..core.text import label_key

log = logging.getLogger(__name__)


def parse_queries(queries: Any, source: str = "") -> dict[str, str]:
    """``{query text: ground-truth label}`` from labels, ``"text=label"`` items or a mapping.

    A label must be text (a mapping's value, not a list or nothing), and a query text
    named twice must name the same label both times; ``source`` (a query file's path)
    starts an error message.

    >>> parse_queries(["chair", "bunk bed=bed", "somewhere to sleep = bed"])
    {'chair': 'chair', 'bunk bed': 'bed', 'somewhere to sleep': 'bed'}
    """
    what = f"{source}: query" if source else "Query"
    if isinstance(queries, dict):
        items = []
        for k, v in queries.items():
            if v is None or not isinstance(v, str):
                given = "no label" if v is None else f"the label {v!r} ({type(v).__name__})"
                raise QuashError(
                    f"{what} {k!r} has {given}; each query names one label by its "
                    f"name, as text ({k}: LABEL, e.g. 'bunk bed: bed'), not by an index "
                    "(quote a label name that reads as a number: 'bunk bed: \"8\"')."
                )
            items.append((str(k), v))
    else:
        items = []
        for q in queries:
            if not isinstance(q, str):
                # '- a seat: stool' in a list, or a label index: str() of it was a query
                # text that no label has, scored as an absence query with nothing said
                raise QuashError(
                    f"{what} item {q!r} ({type(q).__name__}) is not text; in a list, give "
                    "each query as a label name or TEXT=LABEL ('a seat=stool', not 'a seat: "
                    "stool'), or make the whole list a {text: label} mapping; name a label "
                    'by its name, not by an index (quote a name that reads as a number: "8").'
                )
            text, sep, label = q.partition("=")
            if "=" in label:
                raise QuashError(
                    f"{what} item {str(q)!r} holds more than one '=': write TEXT=LABEL, "
                    "one '=' between the query text and its label (e.g. 'bunk bed=bed')."
                )
            items.append((text, label if sep else text))
    out: dict[str, str] = {}
    kept: dict[str, str] = {}  # a query text without case: the spelling scored
    texts: list[str] = []
    for text, label in items:
        text, label = " ".join(text.split()), " ".join(label.split())
        if not text or not label:
            empty = "query text" if not text else "label"
            raise QuashError(
                f"{what} item {(text or '') + '=' + (label or '')!r} has an empty {empty}: "
                "write an open-vocabulary query as TEXT=LABEL (e.g. 'bunk bed=bed'), with "
                "neither side empty."
            )
        first = kept.setdefault(spelling(text), text)
        if label_key(out.get(first, label)) != label_key(label):
            also = f" (as {text!r})" if text != first else ""
            raise QuashError(
                f"{what} {first!r} is given twice{also}, with the labels {out[first]!r} and "
                f"{label!r}: give each query text one ground-truth label."
            )
        out.setdefault(first, label)
        texts.append(text)
    say_twice("queries", one_per_spelling(texts)[1], source)
    return out


def one_per_spelling(texts: Sequence[str]) -> tuple[list[str], dict[str, list[str]]]:
    """``texts`` with each text once whatever its case and spacing (the first spelling
    kept), and ``{kept: [the other spellings dropped]}``.

    >>> one_per_spelling(["piano", "Piano", " piano ", "piano"])
    (['piano'], {'piano': ['Piano', ' piano ']})
    """
    kept: dict[str, str] = {}
    twice: dict[str, list[str]] = {}
    for t in texts:
        first = kept.setdefault(spelling(t), t)
        if t != first and t not in twice.setdefault(first, []):
            twice[first].append(t)
    return list(kept.values()), {k: v for k, v in twice.items() if v}


def say_twice(what: str, twice: dict[str, list[str]], source: str | Path | None = None) -> None:
    """One warning naming the ``what`` ("queries", "absence queries") given more than once
    in another case or spacing (:func:`one_per_spelling`), each scored once."""
    twice = {k: v for k, v in twice.items() if v}
    if twice:
        log.warning(
            "%s%s given more than once in another case or spacing are scored once, as first "
            "written: %s",
            f"{source}: " if source else "",
            what,
            "; ".join(f"{k!r} (also {', '.join(repr(x) for x in v)})" for k, v in twice.items()),
        )


def spelling(text: str) -> str:
    """A query text as two queries are compared: the same query whatever its case and
    spacing (:func:`one_per_spelling`; a present and an absence query are compared so
    too).

    >>> spelling("  Bar  Stool ")
    'bar stool'
    """
    return " ".join(str(text).split()).casefold()


def match_labels(
    gt_of: dict[str, str],
    names: Sequence[str],
    absent: Sequence[str] = (),
    source: str | Path | None = None,
) -> dict[str, str]:
    """Each query's label as the map spells it.

    A label that is not one of the map's ``names`` but is one when case, spacing and
    underscores are ignored ("Robot Arm", "robot_arm") becomes that name. A label that is
    still no name of the map is an object the map does not have, so its query is an
    absence query, with a warning naming it and where it came from (``source``, else
    --queries), except when the label is a near miss of a name of the map (difflib ratio
    at least :data:`TYPO_CUTOFF`: "bedd" for "bed", "chiar" for "chair"): that is refused, naming the query, the close names
    and ``source`` (the query file it came from), since a misspelt label would score an
    object that is there as absent. A label listed among the ``absent`` queries is taken
    as written, and neither it nor a query listed there itself is warned about. (A label
    of the map that no item carries is an absence query too, warned about alike:
    :func:`~quash_plugins.evaluation.report.plan_queries`.)

    >>> match_labels({"a cobot": "Robot Arm", "Forklift": "Forklift"}, ["robot arm", "forklift"])
    {'a cobot': 'robot arm', 'Forklift': 'forklift'}
    >>> match_labels({"a grand piano": "piano"}, ["chair"])
    {'a grand piano': 'piano'}
    """
    exact = set(names)
    folded: dict[str, list[str]] = {}
    for n in names:
        folded.setdefault(label_key(n), []).append(n)
    listed_absent = {label_key(a) for a in absent}
    absent_texts = {spelling(a) for a in absent}  # the query itself listed absent
    out: dict[str, str] = {}
    for text, label in gt_of.items():
        if label not in exact:
            same = folded.get(label_key(label), [])
            if len(same) == 1:
                log.info("query %r: label %r is the map's label %r", text, label, same[0])
                label = same[0]
            elif label_key(label) not in listed_absent:
                near = _near_names(label, names)
                if near:
                    raise QuashError(_typo_message(text, label, near, source))
                if spelling(text) not in absent_texts:
                    warn_scored_absent(text, label, "is not a label of the map", source, comma=True)
        out[text] = label
    return out


def warn_scored_absent(
    text: str, label: str, why: str, source: str | Path | None, comma: bool = False
) -> None:
    """Warn that the present query ``text`` (its ``label``) is scored as an absence query
    because its label ``why`` ("is not a label of the map"), naming where it came from
    (the query file ``source``, else --queries) and how to say it is meant so. With
    ``comma``, a label alone from --queries (no label of the map) may be a part of a query
    text that held a comma (the option splits at every comma): the warning says that such
    a text needs a query file.
    """
    where = f"under 'absent' in {source}" if source else "under --absent"
    alone = spelling(text) == spelling(label)  # a label alone, no TEXT=LABEL
    what = f"query {text!r}" if alone else f"query {text!r}: its label {label!r}"
    hint = (
        "; --queries splits at every comma, so a query text that holds a comma needs --queries-file"
        if comma and alone and not source
        else ""
    )
    log.warning(
        "%s%s %s, so it is scored as an absence query (list it %s to say so%s).",
        f"{source}: " if source else "--queries: ",
        what,
        why,
        where,
        hint,
    )


#: How alike (difflib's ratio, on names folded for case and spacing) a query's label and a
#: label of the map must be for the label to be taken as a misspelling of it and refused.
TYPO_CUTOFF = 0.8


def _near_names(label: str, names: Sequence[str]) -> list[str]:
    """The map's label names that ``label`` is a near miss of (closest first)."""
    from ..core.errors import close_names

    by_fold = {label_key(n): n for n in names}
    return [by_fold[f] for f in close_names(label_key(label), by_fold, cutoff=TYPO_CUTOFF)]


def _typo_message(text: str, label: str, near: list[str], source: str | Path | None) -> str:
    """Why the query ``text`` is refused: its ``label`` is a near miss of ``near``."""
    what = f"{source}: query {text!r}" if source else f"Query {text!r}"
    what += f": its label {label!r}" if text != label else ""
    where = f"under 'absent' in {source}" if source else "to --absent"
    return (
        f"{what} is not a label of the map. Did you mean "
        f"{' or '.join(repr(n) for n in near)}? Write the map's label name; if the object "
        f"is really not in the map, move the query {where} (an absence query)."
    )


#: Keys a query file may hold besides ``present`` and ``absent``: what ``quash make-scene``
#: writes to describe the scene the queries came from.
QUERY_FILE_INFO = ("kind", "room_types", "options", "class_table_sha256", "absent_lookalikes")


def query_file_lookalikes(path: str | Path) -> dict[str, list[str]]:
    """``{absent label: [appearance names]}`` from a query file's ``absent_lookalikes``
    (what ``quash make-scene`` found: appearance names of the scene that read as that
    absent label, :mod:`quash_plugins.demo.lookalikes`); empty when it has none."""
    from ..core.yaml_files import load_yaml

    data, _ = load_yaml(path, "query file")
    return _lookalikes(data)


def _lookalikes(data: Any) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    if isinstance(data, dict):
        for x in data.get("absent_lookalikes") or []:
            if isinstance(x, dict) and "absent" in x and "appearance" in x:
                out.setdefault(str(x["absent"]), []).append(f"{x['appearance']} ({x.get('label')})")
    return out


def load_query_file(path: str | Path) -> tuple[dict[str, str], list[str]]:
    """Presence queries ``{text: label}`` and absence queries from a YAML file
    (:func:`read_query_file` without the look-alikes)."""
    present, absent, _ = read_query_file(path)
    return present, absent


def read_query_file(
    path: str | Path,
) -> tuple[dict[str, str], list[str], dict[str, list[str]]]:
    """Presence queries ``{text: label}`` and absence queries from a YAML file.

    The file is ``{present: ..., absent: [...]}``; ``present`` is a list of labels and
    ``"text=label"`` items or a ``{text: label}`` mapping (``quash make-scene`` writes such
    files: ``SCENE.queries.yaml``, ``SCENE.open-queries.yaml``, with the keys of
    :data:`QUERY_FILE_INFO` too). A plain ``{text: label}`` mapping without those keys is
    all presence queries. A missing file, another key beside ``present`` and ``absent``
    (``presnt``), or a label that is not text is refused, naming the file and the fix.
    The third item is the file's look-alikes (:func:`query_file_lookalikes`), from the
    same single read.
    """
    from ..core.errors import closest
    from ..core.yaml_files import load_yaml

    if not Path(path).exists():  # a pipe, a device or a folder: load_yaml says which
        raise QuashError(
            f"Query file not found: {path}. A query file is YAML {{present: {{text: label}} "
            "or [labels], absent: [texts]} (quash make-scene writes SCENE.queries.yaml)."
        )
    data, _ = load_yaml(path, "query file")

    def unknown_key(key: object, guess: str | None) -> QuashError:
        hint = f" Did you mean {guess!r}?" if guess else ""
        return QuashError(
            f"{path}: unknown key {key!r}; a query file holds 'present' and "
            f"'absent' (and make-scene's {', '.join(QUERY_FILE_INFO)}).{hint}"
        )

    if isinstance(data, dict) and ("present" in data or "absent" in data):
        known = ("present", "absent", *QUERY_FILE_INFO)
        for key in data:
            if key not in known:
                raise unknown_key(key, closest(str(key), ("present", "absent")))
        present, absent = data.get("present") or [], data.get("absent") or []
    elif isinstance(data, dict) and data and all(isinstance(v, list) for v in data.values()):
        # every value a list: {label: [sub-classes]}, a taxonomy given as the query file,
        # unless every key is a misspelt section ('presnt: [chair]' alone): name the key
        near = [closest(str(key), ("present", "absent"), cutoff=0.8) for key in data]
        if all(near):
            raise unknown_key(next(iter(data)), near[0])
        raise QuashError(
            f"{path}: this is a taxonomy ({{label: [sub-class, ...]}}, as make-scene's "
            "SCENE.taxonomy.yaml), not a query file. Give the query file (make-scene's "
            "SCENE.queries.yaml or SCENE.open-queries.yaml: {present: {text: label} or "
            "[labels], absent: [texts]}); a taxonomy goes in the config's heuristic: "
            "{name: taxonomy, file: ...}."
        )
    elif isinstance(data, (dict, list)):
        if isinstance(data, dict):
            # a section under a misspelt name ('presnt: {bunk bed: bed}' alone): no label
            # is a mapping or a list, so say which key is wrong, not that its label is
            for key, value in data.items():
                guess = closest(str(key), ("present", "absent"))
                if isinstance(value, (dict, list)) and guess:
                    raise unknown_key(key, guess)
        present, absent = data, []
    else:
        raise QuashError(
            f"{path}: a query file is a mapping {{present: {{text: label}} or [labels], "
            "absent: [texts]}; see docs/evaluation.md."
        )
    if not isinstance(present, (dict, list)):
        raise QuashError(
            f"{path}: 'present' is {present!r}; write a list of labels ([chair, sofa]) or a "
            "{text: label} mapping (bunk bed: bed)."
        )
    if not isinstance(absent, list):
        example = absent if isinstance(absent, str) else "a giraffe, a grand piano"
        raise QuashError(f"{path}: 'absent' is {absent!r}; write a list of texts ([{example}]).")
    for a in absent:
        if not isinstance(a, str):
            raise QuashError(
                f"{path}: absence query {a!r} ({type(a).__name__}) under 'absent' is not "
                "text; write each absence query as text (quote one that reads as a number "
                'or a mapping: "8", "a seat: stool").'
            )
    absent = [" ".join(a.split()) for a in absent]
    return parse_queries(present, source=str(path)), absent, _lookalikes(data)


__all__ = [
    "label_key",
    "load_query_file",
    "match_labels",
    "one_per_spelling",
    "parse_queries",
    "query_file_lookalikes",
    "read_query_file",
    "say_twice",
    "spelling",
    "warn_scored_absent",
]
