"""The open-vocabulary queries of a proxy scene, and their English.

Per present label with sub-classes, one of its sub-classes as it is or in a near form
(with its article, or in the plural), and the label's free-text description; per absent
label, one of its sub-classes, and the table's absent free text. ``quash make-scene``
writes them to ``SCENE.open-queries.yaml``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..core.text import head_index

if TYPE_CHECKING:
    from .scene import ClassSet


def open_queries(cs: ClassSet, present: list[str], seed: int) -> tuple[dict[str, str], list[str]]:
    """Open-vocabulary queries of a scene: ``{text: label}`` and absent texts.

    Per present label with sub-classes: one of its sub-classes (every other label's in a
    near form: "a X" or a plural) and its free-text description ("somewhere to sleep" ->
    bed); absent: one sub-class of each absent label and the table's absent free text.
    The picks are a hash of the seed and the label, so a scene always has the same ones.
    """
    import hashlib

    def pick(label: str, names: tuple[str, ...]) -> tuple[str, int]:
        h = int(hashlib.sha256(f"open{seed}|{label}".encode()).hexdigest(), 16)
        return names[h % len(names)], h

    def near(name: str, h: int) -> str:
        return with_article(name) if (h >> 8) % 2 == 0 else plural(name)

    language = {c.label: c.language for c in cs.classes}
    out: dict[str, str] = {}
    for i, label in enumerate(present):
        subs = language.get(label) or ()
        if subs:
            sub, h = pick(label, subs)
            out.setdefault(near(sub, h) if i % 2 else sub, label)
    for label in present:
        if label in cs.free_text:
            out.setdefault(cs.free_text[label], label)
    absent = [pick(label, names)[0] for label, names in cs.absent.items()]
    absent += [t for t in cs.absent_free_text_open if t not in absent]
    return out, [a for a in dict.fromkeys(absent) if a not in out]


def with_article(name: str) -> str:
    """``name`` after its indefinite article: "a bed", "an armchair", "a unicycle".

    The article follows the first letter's sound as far as spelling tells it: "an"
    before a vowel, except before the "you" sound of "uni-", "use-", "usu-", "ure-" and
    "eu-"; "a" otherwise (a name that starts with a silent "h" is rare among objects).
    A name that already reads as plural ("dumbbells") takes none.
    """
    if _reads_plural(name):
        return name
    first = name.lstrip().lower()
    vowel = first[:1] in ("a", "e", "i", "o", "u")
    if first.startswith(("uni", "use", "usu", "ure", "eu", "one")):
        vowel = False
    return f"{'an' if vowel else 'a'} {name}"


def _reads_plural(name: str) -> bool:
    """True when the head noun ends in "s" but not "ss", "us" or "is" ("railings")."""
    words = name.lower().split()
    if not words:
        return False
    w = words[head_index(words)]
    return w.endswith("s") and not w.endswith(("ss", "us", "is"))


def plural(name: str) -> str:
    """The plural of an object name: its head noun takes the plural ending.

    The head is the word before "of" ("chests of drawers"), else the last word. A head
    that already reads as plural ("railings", "dumbbells": ends in "s", not "ss", "us"
    or "is") is left as it is; "-y" after a consonant becomes "-ies" ("cubbies"), and
    "-s", "-x", "-z", "-ch", "-sh" take "-es".
    """
    if _reads_plural(name):
        return name
    words = name.split()
    head = head_index(words)
    w = words[head]
    low = w.lower()
    if low.endswith("y") and len(low) > 1 and low[-2] not in "aeiou":
        w = w[:-1] + "ies"
    elif low.endswith(("s", "x", "z", "ch", "sh")):
        w += "es"
    else:
        w += "s"
    words[head] = w
    return " ".join(words)
