"""Class tables of the proxy scene as YAML files: ``quash make-scene --classes FILE.yaml``.

A class table says what a scene is made of: each class's label, the "appearance" names
that build its voxels, the "language" names (sub-classes) that methods are offered, its
colour, where it goes and its size; the room types; the supports that small objects
stand on; the absent labels and free text of the absence queries. The shipped tables A
and B are Python modules (:mod:`.classes`, :mod:`.classes_b`); a file in the same shape
builds a scene from a taxonomy and names of your own, the held-out check the project
cannot see (``quash make-scene --show-classes`` prints table A as a file to start from).

The format (every key required unless marked optional)::

    name: c                          # optional: the table's short name
    classes:
      - label: floor
        appearance: [polished hardwood, grey concrete]   # builds the voxels
        language: [ground, flooring]                     # offered to methods
        color: [150, 120, 90]
        place: structure             # structure | floor | wall | top
        size: [0.5, 0.5, 0.5]        # optional: metres (x, y, z)
    absent: {piano: [grand piano, upright piano]}        # labels in no scene
    absent_free_text: [an elephant]
    supports: [desk]                 # 'floor' labels that 'top' objects stand on
    room_types: {office: [desk, printer]}  # in order: room r gets type r; door and window
                                     # are added to every room
    free_text: {desk: where to do homework}
    absent_free_text_open: [...]     # optional (default: absent_free_text)
    wall_bottom: [door]              # optional: wall objects that stand on the floor
                                     # (default: door, and radiator if the table has one)
    wall_top: [curtain]              # optional: wall objects at the top of the wall
                                     # (default: curtain, if the table has one)

Every table has the labels floor, wall and ceiling (structure), door (wall) and window.
Appearance names differ from every label and language name; each label or language name
belongs to one label (absent ones included, ignoring case); an absent free text names no
class of the table ("a cycle" when a bicycle is in it).

Examples
--------
>>> from quash_plugins.demo.class_file import class_table_data
>>> from quash_plugins.demo.scene import class_set
>>> class_table_data(class_set("a"))["classes"][0]["label"]
'floor'
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from ..core.errors import ConfigError, closest
from .classes import SceneClass

PLACES = ("structure", "floor", "wall", "top")
#: Labels every table needs: the scene builds each room from them.
REQUIRED = {"floor": "structure", "wall": "structure", "ceiling": "structure", "door": "wall"}
REQUIRED_ANY_PLACE = ("window",)
_KEYS = (
    "name",
    "classes",
    "absent",
    "absent_free_text",
    "supports",
    "room_types",
    "free_text",
    "absent_free_text_open",
    "wall_bottom",
    "wall_top",
)
_OPTIONAL = ("name", "absent_free_text_open", "wall_bottom", "wall_top")
_CLASS_KEYS = ("label", "appearance", "language", "color", "place", "size")


def is_class_file(name: str) -> bool:
    """Whether a ``classes`` option names a file rather than a shipped table."""
    return str(name).lower().endswith((".yaml", ".yml"))


def load_class_table(path: str | Path):
    """The :class:`~quash_plugins.demo.scene.ClassSet` of a class-table YAML file.

    Raises :class:`ConfigError` naming the file, the field and the fix.
    """
    import dataclasses
    import hashlib

    from ..core.yaml_files import load_yaml_text

    path = Path(path)
    if not path.is_file():
        raise ConfigError(
            f"{path}: no such class-table file; give --classes a, b or a YAML file "
            "(`quash make-scene --show-classes > my-classes.yaml` writes one to start from)."
        )
    try:  # one read: the bytes parsed are the bytes hashed
        raw = path.read_bytes()
        text = raw.decode("utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read the class-table file: {exc}") from None
    cs = parse_class_table(load_yaml_text(text, str(path)), str(path))
    return dataclasses.replace(cs, sha256=hashlib.sha256(raw).hexdigest())


def parse_class_table(data: Any, where: str = "class table"):
    """Check a class table's mapping (see the module docstring) and build its ClassSet."""
    from .scene import ClassSet

    def fail(field: str, problem: str, fix: str) -> ConfigError:
        return ConfigError(f"{where}: {field}: {problem}; {fix}")

    if not isinstance(data, dict):
        raise fail("top level", "not a mapping", "write the keys classes:, room_types:, ...")
    unknown = sorted(set(map(str, data)) - set(_KEYS))
    if unknown:
        raise fail(unknown[0], "unknown key", f"the keys are {', '.join(_KEYS)}")
    missing = [k for k in _KEYS if k not in data and k not in _OPTIONAL]
    if missing:
        raise fail(missing[0], "missing", "see `quash make-scene --show-classes` for the format")

    def strings(field: str, value: Any, allow_empty: bool = False) -> tuple[str, ...]:
        if isinstance(value, str) or not isinstance(value, (list, tuple)):
            raise fail(field, f"expected a list of names, got {value!r}", "write [name, ...]")
        out = tuple(str(v).strip() for v in value)
        if any(not isinstance(v, (str, int, float)) or not s for v, s in zip(value, out)):
            raise fail(field, "every entry must be a non-empty name", "remove empty entries")
        if not out and not allow_empty:
            raise fail(field, "empty", "give at least one name")
        return out

    def mapping(field: str, value: Any) -> dict:
        if not isinstance(value, dict):
            raise fail(field, f"expected a mapping, got {type(value).__name__}", "write k: v")
        return value

    raw = data["classes"]
    if not isinstance(raw, list) or not raw:
        raise fail("classes", "expected a non-empty list of classes", "write - label: ...")
    classes: list[SceneClass] = []
    for i, c in enumerate(raw):
        at = f"classes[{i}]"
        if not isinstance(c, dict):
            raise fail(at, "expected a mapping", "write label:, appearance:, language:, ...")
        bad = sorted(set(map(str, c)) - set(_CLASS_KEYS))
        if bad:
            raise fail(f"{at}.{bad[0]}", "unknown key", f"a class has {', '.join(_CLASS_KEYS)}")
        for key in ("label", "appearance", "language", "color", "place"):
            if key not in c:
                raise fail(f"{at}.{key}", "missing", "every class needs it")
        label = str(c["label"]).strip()
        if not label:
            raise fail(f"{at}.label", "empty", "name the class")
        at = f"classes[{i}] ({label})"
        place = c["place"]
        if place not in PLACES:
            raise fail(f"{at}.place", f"{place!r}", f"one of {', '.join(PLACES)}")
        color = c["color"]
        if (
            not isinstance(color, (list, tuple))
            or len(color) != 3
            or not all(isinstance(v, int) and 0 <= v <= 255 for v in color)
        ):
            raise fail(f"{at}.color", f"{color!r}", "three integers 0-255, e.g. [150, 120, 90]")
        size = c.get("size", (0.5, 0.5, 0.5))
        if (
            not isinstance(size, (list, tuple))
            or len(size) != 3
            or not all(isinstance(v, (int, float)) and 0 < v <= 20 for v in size)
        ):
            raise fail(f"{at}.size", f"{size!r}", "three lengths in metres (x, y, z), each > 0")
        classes.append(
            SceneClass(
                label,
                strings(f"{at}.appearance", c["appearance"]),
                strings(f"{at}.language", c["language"], allow_empty=True),
                tuple(int(v) for v in color),
                place,
                tuple(float(v) for v in size),
            )
        )
    by_label: dict[str, SceneClass] = {}
    for c in classes:
        if c.label in by_label:
            raise fail("classes", f"label {c.label!r} twice", "give each label once")
        by_label[c.label] = c
    for label, place in REQUIRED.items():
        if label not in by_label:
            raise fail("classes", f"no {label!r} class", f"add it with place: {place}")
        if by_label[label].place != place:
            raise fail(f"classes ({label}).place", by_label[label].place, f"it must be {place}")
    for label in REQUIRED_ANY_PLACE:
        if label not in by_label:
            raise fail("classes", f"no {label!r} class", "add it (place: wall)")

    def labels(field: str, value: Any, place: str | None = None) -> tuple[str, ...]:
        names = strings(field, value, allow_empty=True)
        for n in names:
            if n not in by_label:
                guess = closest(n, by_label)
                fix = f"did you mean {guess!r}? Else add" if guess else "add"
                raise fail(field, f"{n!r} is not a class label", f"{fix} the class or remove it")
            if place and by_label[n].place != place:
                raise fail(field, f"{n!r} has place {by_label[n].place}", f"it must be {place}")
        return names

    supports = labels("supports", data["supports"], "floor")
    room_types: dict[str, tuple[str, ...]] = {}
    for room, names in mapping("room_types", data["room_types"]).items():
        room_types[str(room)] = labels(f"room_types.{room}", names)
        placed = [n for n in room_types[str(room)] if by_label[n].place == "structure"]
        if placed:
            raise fail(
                f"room_types.{room}", f"{placed[0]!r} is structure", "every room has it already"
            )
        tops = [n for n in room_types[str(room)] if by_label[n].place == "top"]
        if tops and not set(room_types[str(room)]) & set(supports):
            raise fail(
                f"room_types.{room}",
                f"{tops[0]!r} goes on top of a support but the room has none",
                f"add one of the supports ({', '.join(supports) or 'none listed'})",
            )
    if not room_types:
        raise fail("room_types", "empty", "give at least one room type")
    free_text: dict[str, str] = {}
    for label, text in mapping("free_text", data["free_text"]).items():
        if str(label) not in by_label:
            raise fail(f"free_text.{label}", "not a class label", "add the class or remove it")
        if not isinstance(text, str) or not text.strip():
            raise fail(f"free_text.{label}", f"{text!r}", "write a description as text")
        free_text[str(label)] = text.strip()
    absent: dict[str, tuple[str, ...]] = {}
    for label, names in mapping("absent", data["absent"]).items():
        if str(label) in by_label:
            raise fail(f"absent.{label}", "is a class of the table", "an absent label is in none")
        absent[str(label)] = strings(f"absent.{label}", names or [])  # its sub-classes
    absent_free_text = strings("absent_free_text", data["absent_free_text"], allow_empty=True)
    open_text = data.get("absent_free_text_open")
    open_text = (
        absent_free_text if open_text is None else strings("absent_free_text_open", open_text)
    )
    # the defaults (table A's) only where the table has those labels
    default_bottom = [n for n in ("door", "radiator") if n in by_label]
    default_top = [n for n in ("curtain",) if n in by_label]
    wall_bottom = labels("wall_bottom", data.get("wall_bottom", default_bottom), "wall")
    wall_top = labels("wall_top", data.get("wall_top", default_top), "wall")

    owner: dict[str, str] = {}  # each label and language name answers to one label
    named = [(f"classes[{i}] ({c.label}).label", c.label, c.label) for i, c in enumerate(classes)]
    named += [
        (f"classes[{i}] ({c.label}).language", c.label, n)
        for i, c in enumerate(classes)
        for n in c.language
    ]
    named += [(f"absent.{a}", a, n) for a, subs in absent.items() for n in (a, *subs)]
    for field, label, n in named:
        if owner.setdefault(n.lower(), label) != label:
            raise fail(
                field,
                f"{n!r} is also a name of {owner[n.lower()]!r}",
                "give each label and language name to one label (a query has one answer)",
            )
    for field, texts in (
        ("absent_free_text", absent_free_text),
        ("absent_free_text_open", open_text),
    ):
        for t in texts:
            bare = re.sub(r"^(an?|the)\s+", "", t.lower())
            if bare in owner and owner[bare] in by_label:
                raise fail(
                    field,
                    f"{t!r} names {owner[bare]!r}, a class of the table",
                    "an absence query names nothing in the scene; remove it or reword it",
                )
    both = shared_names(classes, absent)
    if both:
        name, label = both[0]
        raise fail(
            f"classes ({label}).appearance",
            f"{name!r} is also a label or language name",
            "appearance and language names must differ (methods never see appearance names)",
        )
    return ClassSet(
        str(data.get("name") or Path(where).stem),
        tuple(classes),
        absent,
        absent_free_text,
        supports,
        room_types,
        free_text,
        open_text,
        wall_bottom,
        wall_top,
    )


def shared_names(classes, absent: dict[str, Any]) -> list[tuple[str, str]]:
    """``(appearance name, its class)`` for each appearance name that is also a label or
    a language name of the table (absent ones included), ignoring case, sorted. No
    method may embed a string that built the voxels (the taxonomy offers only language
    names), so a valid table has none."""
    appearance = {n.lower(): c.label for c in classes for n in c.appearance}
    offered = {c.label.lower() for c in classes} | {n.lower() for c in classes for n in c.language}
    offered |= {a.lower() for a in absent} | {n.lower() for v in absent.values() for n in v}
    return [(n, appearance[n]) for n in sorted(set(appearance) & offered)]


def class_table_data(cs) -> dict[str, Any]:
    """A ClassSet as the mapping a class-table file holds (``--show-classes``)."""
    return {
        "name": cs.name,
        "classes": [
            {
                "label": c.label,
                "appearance": list(c.appearance),
                "language": list(c.language),
                "color": list(c.color),
                "place": c.place,
                "size": [float(v) for v in c.size],
            }
            for c in cs.classes
        ],
        "absent": {k: list(v) for k, v in cs.absent.items()},
        "absent_free_text": list(cs.absent_free_text),
        "supports": list(cs.supports),
        "room_types": {k: list(v) for k, v in cs.room_types.items()},
        "free_text": dict(cs.free_text),
        "absent_free_text_open": list(cs.absent_free_text_open),
        "wall_bottom": list(cs.wall_bottom),
        "wall_top": list(cs.wall_top),
    }
