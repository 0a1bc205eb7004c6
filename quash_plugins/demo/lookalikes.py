"""Appearance names that read as an absent object: a check of a class table.

The proxy scene builds each voxel from the text embeddings of its class's appearance
names, so an appearance name that the encoder places nearer an *absent* label's names
than its own class's names puts that absent object into the map's features. A table of
your own can do it by accident: with MiniLM, "terracotta tiles" (a floor) has cosine
0.605 to "terrarium" (a sub-class of the absent aquarium) and at most 0.261 to the floor's
names, and every method's features-first answer to "aquarium" is then that floor. Such a
scene's ground truth says "absent" where its features say "present".

:func:`absent_lookalikes` finds them; ``quash make-scene`` logs each one as a warning and
writes them to ``SCENE.queries.yaml`` and ``SCENE.open-queries.yaml``
(``absent_lookalikes``), and ``quash eval --queries-file`` warns about them, so that an
absence query lost to one can be told from a method's false match.

Examples
--------
>>> import numpy as np
>>> from quash_plugins.demo.classes import SceneClass
>>> class Enc:  # two axes: floor-like and aquarium-like (unit rows, as encoders give)
...     dim = 2
...     rows = {"floor": [1, 0], "ground": [1, 0.1], "tile": [0.2, 1], "plank": [1, 0.2],
...             "aquarium": [0, 1], "fish tank": [0.1, 1]}
...     def encode_text(self, texts):
...         x = np.asarray([self.rows[t] for t in texts], np.float32)
...         return x / np.linalg.norm(x, axis=1, keepdims=True)
>>> floor = SceneClass("floor", ("tile", "plank"), ("ground",), (0, 0, 0), "structure")
>>> [(x.appearance, x.absent) for x in absent_lookalikes([floor], {"aquarium": ("fish tank",)}, Enc())]
[('tile', 'aquarium')]
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

log = logging.getLogger(__name__)

#: How much nearer (in cosine) an absent label's best name must be than the class's own
#: best name for an appearance name to count as a look-alike. Tables A, B and C stay under
#: it with MiniLM (their largest lead is 0.165: "trailing ivy in terracotta" to
#: "terrarium" on table B), and the presence check keeps those absent objects out; the
#: two names of the fourth table that let one in lead by 0.29 and 0.345
#: (docs/benchmarks.md, "A fourth class table").
LEAD = 0.2


@dataclass(frozen=True)
class Lookalike:
    """An appearance name of ``label`` nearer the absent ``absent`` than its own names."""

    label: str
    appearance: str
    absent: str
    absent_name: str  # the absent label's name (or sub-class) it is nearest to
    cosine: float
    own_name: str  # the nearest of its own class's names (label and language)
    own_cosine: float

    def words(self) -> str:
        return (
            f"appearance name {self.appearance!r} of {self.label!r} is nearer the absent "
            f"{self.absent!r} ({self.absent_name!r}: cosine {self.cosine:.3f}) than any "
            f"{self.label!r} name ({self.own_name!r}: {self.own_cosine:.3f})"
        )

    def record(self) -> dict[str, Any]:
        out = asdict(self)
        out["cosine"] = round(self.cosine, 4)
        out["own_cosine"] = round(self.own_cosine, 4)
        return out


def absent_lookalikes(
    classes: Sequence[Any],
    absent: Mapping[str, Sequence[str]],
    encoder: Any,
    cache: Any = None,
    lead: float = LEAD,
) -> list[Lookalike]:
    """Every appearance name of ``classes`` whose best cosine to an absent label's names
    (the label and its sub-classes, ``absent``) exceeds its best cosine to its own class's
    names (label and language names) by more than ``lead``, nearest absent label first.
    ``encoder`` embeds the names (``cache``: a text-embedding cache, as the scene uses)."""
    from ..core.text import encode_texts

    if not absent:
        return []
    groups: dict[str, tuple[str, ...]] = {c.label: (c.label, *c.language) for c in classes}
    gone = {k: (k, *v) for k, v in absent.items()}
    names = sorted(
        {n for c in classes for n in c.appearance}
        | {n for g in (*groups.values(), *gone.values()) for n in g}
    )
    row = {n: i for i, n in enumerate(names)}
    emb = encode_texts(encoder, names, cache)  # unit-norm rows
    gone_emb = {k: emb[[row[n] for n in members]] for k, members in gone.items()}
    found = []
    for c in classes:
        own = emb[[row[n] for n in groups[c.label]]]
        for a in c.appearance:
            v = emb[row[a]]
            own_cos = own @ v
            best_own = int(np.argmax(own_cos))
            for label, members in gone.items():
                cos = gone_emb[label] @ v
                j = int(np.argmax(cos))
                if cos[j] > own_cos[best_own] + lead:
                    found.append(
                        Lookalike(
                            c.label,
                            a,
                            label,
                            members[j],
                            float(cos[j]),
                            groups[c.label][best_own],
                            float(own_cos[best_own]),
                        )
                    )
    return sorted(found, key=lambda x: x.own_cosine - x.cosine)


def scene_lookalikes(
    cs: Any, present: Sequence[str], encoder: Any, cache: Any = None
) -> list[dict]:
    """What ``make_scene`` records: the look-alikes among the appearance names of the
    classes in the map (``present``) of class table ``cs``, each logged as a warning, as
    plain records for ``SCENE.queries.yaml``. An encoder that cannot embed the label and
    language names (a table encoder holding the appearance names only) skips the check."""
    from ..core.errors import EncoderError

    in_map = set(present)
    here = [c for c in cs.classes if c.label in in_map]
    try:
        found = absent_lookalikes(here, cs.absent, encoder, cache)
    except EncoderError as exc:
        log.info("skipped the check for appearance names that read as absent labels: %s", exc)
        return []
    for x in found:
        log.warning(
            "class table %s: %s, so this scene's features hold what the absence query %r "
            "asks for; rename that appearance name (quash make-scene --show-classes "
            "prints the format)",
            cs.name,
            x.words(),
            x.absent,
        )
    return [x.record() for x in found]
