"""Robust parsing of a language model's synonym/antonym reply.

A reasoning model's thoughts (``<think>...</think>``, also ``<thinking>`` and
``<reasoning>``, or a reply that starts inside them and holds only the closing tag) are
removed first: a draft list in them is not the answer.

Accepted forms, tried in order:

1. A JSON object ``{"synonyms": [...], "antonyms": [...]}``, bare, inside a
   ```` ```json ```` fence, or embedded in prose (the first balanced ``{...}`` that parses).
   ``positives``/``negatives`` are accepted as key aliases; a string value is split
   like a list.
2. Sections introduced by a heading that names synonyms or antonyms (``Synonyms:``,
   ``**Antonyms**``, ``## Antonyms``), each holding a numbered or bulleted list, one
   item per line, or a comma-separated list (also on the heading line itself).

Parsing costs time linear (or n log n) in the reply's length: the JSON candidates are
decoded by the C decoder from at most 20 opening braces, thoughts are removed in one pass,
an item longer than :data:`MAX_ITEM_CHARS` is dropped before it is normalised, and only
the first :data:`MAX_ITEMS_READ` items of each list are read. Text
quoted in an error is redacted (with the secrets given) before it is shortened, so that a
key cut in two can never show its first half.
"""

from __future__ import annotations

import bisect
import itertools
import json
import re
from collections.abc import Callable, Iterable, Iterator
from typing import Any

from ..core.redact import redact_start
from ._taxonomy import normalise_name

_SYN_KEYS = ("synonyms", "synonym", "positives", "positive")
_ANT_KEYS = ("antonyms", "antonym", "negatives", "negative")
_FENCE = re.compile(r"```(?:json|JSON)?\s*(.*?)```", re.S)
_HEADING = re.compile(
    r"^[\s#>*_\-\d.)]*\b(synonyms?|antonyms?|positives?|negatives?)\b[\s*_:\-]*(.*)$", re.I
)
_BULLET = re.compile(r"^\s*(?:[-*+\u2022]|\(?\d{1,3}[.):]|[a-zA-Z][.)])\s+")
_MAX_WORDS = 6
#: List separators: comma, semicolon, and the full-width and ideographic ones (，；、).
_SEPARATORS = re.compile(r"[,;\uff0c\uff1b\u3001]")
#: Stripped from both ends of an item: quotes (straight, curly, CJK corner brackets),
#: emphasis and sentence punctuation, ASCII and full-width.
_STRIP = "\"'`*_.,;:!?\u2018\u2019\u201c\u201d\u201e\u00ab\u00bb\u300c\u300d\u300e\u300f\u3002\u3001\uff0c\uff1b\uff1a\uff01\uff1f"
_MAX_CHARS = 60
#: An item longer than this, before normalising, is dropped unread: no note or numbering
#: stripped from it could bring it under :data:`_MAX_CHARS`, and the normalising patterns
#: cost time that grows faster than its length.
MAX_ITEM_CHARS = 1000
#: Items of each list read from a reply: a list asked for is 20 or so items long, and
#: each item costs a few tens of microseconds to normalise and check.
MAX_ITEMS_READ = 10_000
#: Opening braces of a reply (and fenced blocks) tried as the start of a JSON object.
_MAX_JSON_STARTS = 20
_DECODER = json.JSONDecoder()
_THOUGHT_TAGS = "think|thinking|reasoning"
_THOUGHT_TAG = re.compile(rf"<(/?)({_THOUGHT_TAGS})(\s*)>", re.I)
_THOUGHTS_END = re.compile(rf"</(?:{_THOUGHT_TAGS})\s*>", re.I)
_THOUGHTS_OPEN = re.compile(rf"<(?:{_THOUGHT_TAGS})>", re.I)


def parse_reply(
    text: str, secrets: Iterable[str | None] = (), cut_off: bool = False
) -> tuple[list[str], list[str]]:
    """Return raw ``(synonyms, antonyms)`` from a reply; ValueError when neither is found.

    ``secrets`` (the API key) are redacted from the reply quoted in the ValueError before
    it is shortened. ``cut_off``: the reply stopped at the token limit (``finish_reason``
    ``length``), so only a whole JSON object is taken: a list of lines or commas read up
    to the cut would end in a cut item ("la" of "lamp") and lack the rest.

    Examples
    --------
    >>> parse_reply('Sure! ```json\\n{"synonyms": ["seat"], "antonyms": ["table"]}\\n```')
    (['seat'], ['table'])
    >>> parse_reply("Synonyms:\\n1. seat\\n2. stool\\nAntonyms: table, lamp")
    (['seat', 'stool'], ['table', 'lamp'])
    """
    if not isinstance(text, str) or not text.strip():
        raise ValueError("empty reply")
    secrets = list(secrets)
    text = _drop_thoughts(text, secrets)
    for obj in _json_candidates(text):
        found = _from_json(obj)
        if found is not None:
            return found
    if cut_off:
        raise ValueError(f"no whole JSON lists before the cut in {_short(text, secrets)}")
    found = _from_sections(text)
    if found is not None:
        return found
    raise ValueError(f"no synonyms/antonyms lists found in {_short(text, secrets)}")


def clean_lists(
    query: str,
    synonyms: list[str],
    antonyms: list[str],
    n_syn: int,
    n_ant: int,
    keep: Callable[[str], bool] | None = None,
) -> tuple[list[str], list[str]]:
    """Normalise, dedupe and cap; drop the query and synonyms from the antonyms.

    ``keep``, when given, is asked about each raw item before it is normalised (the
    heuristic drops an item that carries a credential). Items are read only until the
    caps are reached, and at most :data:`MAX_ITEMS_READ` of each list, so a reply with a
    million items costs little more than one with the counts asked.

    Examples
    --------
    >>> clean_lists("chair", ["Seat", "seat", "chair"], ["chair", "seat", "table"], 5, 5)
    (['seat'], ['table'])
    >>> clean_lists("chair", ["seat"], ["chairs", "a chair", "seats", "tables"], 5, 5)
    (['seat'], ['tables'])
    """
    q = _norm(query)
    syn = list(itertools.islice((s for s in _dedupe(synonyms, keep) if s != q), max(0, n_syn)))
    # an antonym that names the query or a synonym in another number or with an article
    # ("chairs", "a chair") would be a negative for the very thing asked for
    taken = {normalise_name(w) for w in (q, *syn)}
    ant = list(
        itertools.islice(
            (a for a in _dedupe(antonyms, keep) if normalise_name(a) not in taken), max(0, n_ant)
        )
    )
    return syn, ant


def _drop_thoughts(text: str, secrets: Iterable[str | None] = ()) -> str:
    """``text`` without a reasoning model's thoughts; ValueError when nothing else is left.

    >>> _drop_thoughts('<think>maybe {"synonyms": ["x"]}</think> {"synonyms": ["seat"]}')
    ' {"synonyms": ["seat"]}'
    """
    out = _drop_closed_thoughts(text)
    ends = list(_THOUGHTS_END.finditer(out))
    if ends:  # the opening tag was in the prompt's template: thoughts run up to the last end
        out = out[ends[-1].end() :]
    opened = _THOUGHTS_OPEN.search(out)
    if opened:  # never closed: the model ran out of tokens while thinking
        out = out[: opened.start()]
    if not out.strip():
        raise ValueError(
            "the reply holds only the model's reasoning "
            f"({_short(text, secrets)}), no answer after it"
        )
    return out


def _drop_closed_thoughts(text: str) -> str:
    """``text`` without each ``<think>...</think>`` (also ``thinking``, ``reasoning``; any
    case): from the leftmost opening tag to the first closing tag of its name after it,
    then on from there. One pass over the tags (a pattern with ``.*?`` rescanned the rest
    of the text from every opening tag that is never closed)."""
    opens: list[tuple[int, int, str]] = []
    closes: dict[str, list[tuple[int, int]]] = {}
    for m in _THOUGHT_TAG.finditer(text):
        name = m.group(2).lower()
        if m.group(1):
            closes.setdefault(name, []).append((m.start(), m.end()))
        elif not m.group(3):  # "<think >" opens nothing; "</think >" closes
            opens.append((m.start(), m.end(), name))
    if not opens or not closes:
        return text
    kept: list[str] = []
    pos = 0
    for start, end, name in opens:
        if start < pos:
            continue
        ends = closes.get(name, [])
        i = bisect.bisect_left(ends, (end, end))
        if i == len(ends):
            continue
        kept.append(text[pos:start])
        pos = ends[i][1]
    kept.append(text[pos:])
    return "".join(kept)


# ---------------------------------------------------------------------- JSON
def _json_candidates(text: str) -> list[Any]:
    """Each fenced block and the whole text: parsed whole, else the first JSON value that
    starts at one of its first 20 opening braces (the C decoder reads one value and stops;
    a Python scan for the matching brace, from each start to the end, took 11 s on a
    2 MB reply)."""
    out: list[Any] = []
    fences = itertools.islice(_FENCE.finditer(text), _MAX_JSON_STARTS)
    blocks = [m.group(1) for m in fences] + [text]
    for block in blocks:
        try:
            out.append(json.loads(block))
            continue
        except (ValueError, RecursionError):  # RecursionError: nesting too deep
            pass
        start = block.find("{")
        for _ in range(_MAX_JSON_STARTS):
            if start < 0:
                break
            try:
                out.append(_DECODER.raw_decode(block, start)[0])
                break
            except (ValueError, RecursionError):
                start = block.find("{", start + 1)
    return out


def _from_json(obj: Any) -> tuple[list[str], list[str]] | None:
    if not isinstance(obj, dict):
        return None
    low = {str(k).strip().lower(): v for k, v in obj.items()}
    syn_key = next((k for k in _SYN_KEYS if k in low), None)
    ant_key = next((k for k in _ANT_KEYS if k in low), None)
    if syn_key is None and ant_key is None:
        return None
    return _as_list(low.get(syn_key)), _as_list(low.get(ant_key))


def _as_list(value: Any) -> list[str]:
    if value is None:
        return []
    if isinstance(value, str):
        return _split_items(value)
    if isinstance(value, (list, tuple)):
        out = []
        for v in value:
            if isinstance(v, str):
                out.append(v)
            elif isinstance(v, dict):  # e.g. {"word": "seat"} or {"name": ...}
                text = next((x for x in v.values() if isinstance(x, str)), None)
                if text:
                    out.append(text)
        return out
    raise ValueError(f"expected a list, got {type(value).__name__}")


# ---------------------------------------------------------------------- text lists
def _from_sections(text: str) -> tuple[list[str], list[str]] | None:
    sections: dict[str, list[str]] = {}
    current: str | None = None
    for line in text.splitlines():
        head = _HEADING.match(line)
        if head and _is_heading(line, head):
            word = head.group(1).lower()
            current = "syn" if word.startswith(("syn", "pos")) else "ant"
            sections.setdefault(current, [])
            rest = head.group(2).strip()
            if rest:
                sections[current].extend(_split_items(rest))
            continue
        if current is None or not line.strip():
            continue
        sections[current].extend(_split_items(line))
    if not sections:
        return None
    return sections.get("syn", []), sections.get("ant", [])


def _is_heading(line: str, match: re.Match) -> bool:
    # "Synonyms:" / "**Antonyms**" / "## Synonyms (20)" but not "1. synonym dictionary"
    before = line[: match.start(1)]
    return not _BULLET.match(line) or bool(re.search(r"[#*]", before))


def _split_items(line: str) -> list[str]:
    line = _BULLET.sub("", line.strip())
    parts = re.split(r"[,;\n\uff0c\uff1b\u3001]", line) if _SEPARATORS.search(line) else [line]
    return [p for p in (x.strip() for x in parts) if p]


# ---------------------------------------------------------------------- items
def _norm(item: str) -> str:
    s = _BULLET.sub("", str(item).strip())
    s = re.sub(r"\s*[\(\[].*?[\)\]]\s*", " ", s)  # "(optional)" notes
    s = re.sub(r"\s+[-\u2013\u2014:]\s+.*$", "", s)  # "seat - used for sitting"
    s = s.strip().strip(_STRIP).strip()
    return " ".join(s.lower().split())


def _dedupe(items: list[str], keep: Callable[[str], bool] | None = None) -> Iterator[str]:
    seen: set[str] = set()
    seen_raw: set[str] = set()  # an item repeated verbatim is judged once
    for raw in itertools.islice(items, MAX_ITEMS_READ):
        if raw in seen_raw:
            continue
        seen_raw.add(raw)
        if len(str(raw)) > MAX_ITEM_CHARS or (keep is not None and not keep(raw)):
            continue
        s = _norm(raw)
        if not s or s in seen or len(s) > _MAX_CHARS or len(s.split()) > _MAX_WORDS:
            continue
        if not any(c.isalnum() for c in s):  # a letter or digit of any script
            continue
        seen.add(s)
        yield s


def _short(text: str, secrets: Iterable[str | None] = (), n: int = 120) -> str:
    """The start of ``text`` for a message: redacted first, then shortened (a key cut at
    the 120th character no longer matched the key, and its first part showed)."""
    return redact_start(text, secrets, n)
