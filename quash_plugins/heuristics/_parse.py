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
"""

from __future__ import annotations

import json
import re
from typing import Any

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
_THOUGHT_TAGS = "think|thinking|reasoning"
_THOUGHTS = re.compile(rf"<({_THOUGHT_TAGS})>.*?</\1\s*>", re.S | re.I)
_THOUGHTS_END = re.compile(rf"</(?:{_THOUGHT_TAGS})\s*>", re.I)
_THOUGHTS_OPEN = re.compile(rf"<(?:{_THOUGHT_TAGS})>", re.I)


def parse_reply(text: str) -> tuple[list[str], list[str]]:
    """Return raw ``(synonyms, antonyms)`` from a reply; ValueError when neither is found.

    Examples
    --------
    >>> parse_reply('Sure! ```json\\n{"synonyms": ["seat"], "antonyms": ["table"]}\\n```')
    (['seat'], ['table'])
    >>> parse_reply("Synonyms:\\n1. seat\\n2. stool\\nAntonyms: table, lamp")
    (['seat', 'stool'], ['table', 'lamp'])
    """
    if not isinstance(text, str) or not text.strip():
        raise ValueError("empty reply")
    text = _drop_thoughts(text)
    for obj in _json_candidates(text):
        found = _from_json(obj)
        if found is not None:
            return found
    found = _from_sections(text)
    if found is not None:
        return found
    raise ValueError(f"no synonyms/antonyms lists found in {_short(text)}")


def clean_lists(
    query: str, synonyms: list[str], antonyms: list[str], n_syn: int, n_ant: int
) -> tuple[list[str], list[str]]:
    """Normalise, dedupe and cap; drop the query and synonyms from the antonyms.

    Examples
    --------
    >>> clean_lists("chair", ["Seat", "seat", "chair"], ["chair", "seat", "table"], 5, 5)
    (['seat'], ['table'])
    """
    q = _norm(query)
    syn = [s for s in _dedupe(synonyms) if s != q][: max(0, n_syn)]
    taken = {q, *syn}
    ant = [a for a in _dedupe(antonyms) if a not in taken][: max(0, n_ant)]
    return syn, ant


def _drop_thoughts(text: str) -> str:
    """``text`` without a reasoning model's thoughts; ValueError when nothing else is left.

    >>> _drop_thoughts('<think>maybe {"synonyms": ["x"]}</think> {"synonyms": ["seat"]}')
    ' {"synonyms": ["seat"]}'
    """
    out = _THOUGHTS.sub("", text)
    ends = list(_THOUGHTS_END.finditer(out))
    if ends:  # the opening tag was in the prompt's template: thoughts run up to the last end
        out = out[ends[-1].end() :]
    opened = _THOUGHTS_OPEN.search(out)
    if opened:  # never closed: the model ran out of tokens while thinking
        out = out[: opened.start()]
    if not out.strip():
        raise ValueError(
            f"the reply holds only the model's reasoning ({_short(text)}), no answer after it"
        )
    return out


# ---------------------------------------------------------------------- JSON
def _json_candidates(text: str) -> list[Any]:
    out: list[Any] = []
    blocks = [m.group(1) for m in _FENCE.finditer(text)] + [text]
    for block in blocks:
        try:
            out.append(json.loads(block))
            continue
        except ValueError:
            pass
        for start in [i for i, c in enumerate(block) if c == "{"][:20]:
            sub = _balanced(block, start)
            if sub is None:
                continue
            try:
                out.append(json.loads(sub))
                break
            except ValueError:
                continue
    return out


def _balanced(text: str, start: int) -> str | None:
    depth, in_str, esc = 0, False, False
    for i in range(start, len(text)):
        c = text[i]
        if in_str:
            if esc:
                esc = False
            elif c == "\\":
                esc = True
            elif c == '"':
                in_str = False
        elif c == '"':
            in_str = True
        elif c == "{":
            depth += 1
        elif c == "}":
            depth -= 1
            if depth == 0:
                return text[start : i + 1]
    return None


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


def _dedupe(items: list[str]) -> list[str]:
    out: list[str] = []
    seen: set[str] = set()
    for raw in items:
        s = _norm(raw)
        if not s or s in seen or len(s) > _MAX_CHARS or len(s.split()) > _MAX_WORDS:
            continue
        if not any(c.isalnum() for c in s):  # a letter or digit of any script
            continue
        seen.add(s)
        out.append(s)
    return out


def _short(text: str, n: int = 120) -> str:
    text = " ".join(text.split())
    return repr(text if len(text) <= n else text[:n] + "...")
