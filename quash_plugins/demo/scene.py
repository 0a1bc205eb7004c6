"""A 3D indoor proxy scene whose voxel embeddings come from a real text encoder.

Rooms in a row share walls; each has a floor, walls, a ceiling, a door, a window and
the furniture of its room type. Every voxel's embedding is the normalised mean of a few
"appearance" names of its object's class, blended with a neighbouring object's embedding
at boundaries, plus Gaussian noise and one constant "modality offset" (image embeddings
of real maps sit apart from the text embeddings that query them). The taxonomy YAML
written next to the map holds only the disjoint "language" names, so no method embeds
the strings that built the voxels.

The layout is :mod:`._scene_layout`, the embeddings :mod:`._scene_embed` and the files
:mod:`._scene_files` (``write_scene``, ``scene_paths``, ``is_scene_file``, importable
from here).

Examples
--------
>>> from quash_plugins.demo.scene import SceneOptions
>>> SceneOptions(rooms=1).rooms
1
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..core.errors import ConfigError
from ..core.types import LatentMap
from ._scene_embed import _built_by, voxel_embeddings
from ._scene_files import is_scene_file, scene_paths, write_scene  # noqa: F401 (public here)
from ._scene_layout import _layout
from .classes import ABSENT, ABSENT_FREE_TEXT, CLASSES, SUPPORTS, SceneClass
from .lookalikes import scene_lookalikes
from .queries import open_queries

log = logging.getLogger(__name__)

ROOM_TYPES: dict[str, tuple[str, ...]] = {
    "living room": (
        "sofa",
        "table",
        "chair",
        "tv",
        "picture",
        "lamp",
        "plant",
        "cushion",
        "rug",
        "shelf",
        "book",
        "vase",
        "clock",
        "curtain",
        "radiator",
    ),
    "kitchen": (
        "counter",
        "refrigerator",
        "stove",
        "sink",
        "cabinet",
        "table",
        "chair",
        "trash can",
        "clock",
        "vase",
        "towel",
    ),
    "bedroom": (
        "bed",
        "cabinet",
        "lamp",
        "picture",
        "mirror",
        "curtain",
        "rug",
        "cushion",
        "book",
        "desk",
        "chair",
    ),
    "bathroom": ("toilet", "sink", "mirror", "towel", "cabinet", "trash can", "radiator"),
    "office": (
        "desk",
        "chair",
        "laptop",
        "shelf",
        "book",
        "lamp",
        "plant",
        "trash can",
        "picture",
        "clock",
    ),
}


@dataclass(frozen=True)
class ClassSet:
    """A class table with its room types, placement rules and open-vocabulary queries."""

    name: str
    classes: tuple[SceneClass, ...]
    absent: dict[str, tuple[str, ...]]
    absent_free_text: tuple[str, ...]
    supports: tuple[str, ...]
    room_types: dict[str, tuple[str, ...]]
    free_text: dict[str, str]
    absent_free_text_open: tuple[str, ...]
    wall_bottom: tuple[str, ...] = ("door", "radiator")
    wall_top: tuple[str, ...] = ("curtain",)
    #: sha256 of the file's bytes it was parsed from (a class-table file), else None
    sha256: str | None = None


#: The class tables ``SceneOptions.classes`` may name.
CLASS_TABLES = ("a", "b")


def class_set(name: str) -> ClassSet:
    """``"a"``: the project's table (:mod:`.classes`); ``"b"``: the second one
    (:mod:`.classes_b`: other labels, other names, no shared word); a ``.yaml`` path: a
    class-table file of your own (:mod:`.class_file`)."""
    from .class_file import is_class_file, load_class_table

    if is_class_file(name):
        return load_class_table(name)
    if name == "a":
        from .classes import ABSENT_FREE_TEXT_OPEN, FREE_TEXT_A

        return ClassSet(
            "a",
            CLASSES,
            ABSENT,
            ABSENT_FREE_TEXT,
            SUPPORTS,
            ROOM_TYPES,
            FREE_TEXT_A,
            ABSENT_FREE_TEXT_OPEN,
        )
    if name == "b":
        from . import classes_b as b

        return ClassSet(
            "b",
            b.CLASSES_B,
            b.ABSENT_B,
            b.ABSENT_FREE_TEXT_B,
            b.SUPPORTS_B,
            b.ROOM_TYPES_B,
            b.FREE_TEXT_B,
            b.ABSENT_FREE_TEXT_B,
            b.WALL_BOTTOM_B,
            b.WALL_TOP_B,
        )
    raise ConfigError(
        f"scene option classes must be one of {', '.join(CLASS_TABLES)} or a class-table "
        f"YAML file; got {name!r}."
    )


@dataclass
class SceneOptions:
    """Options of :func:`make_scene` (the CLI exposes each as ``--option``).

    Defaults resemble real maps: surfaces only, most voxels wall, floor or ceiling, small
    objects, mixed boundaries, noisy embeddings and a modality offset.
    """

    seed: int = 0
    rooms: int = 5
    room_size: float = 4.5
    room_height: float = 2.6
    voxel_size: float = 0.1
    extra_objects: int = 2
    names_per_voxel: int = 3
    boundary_blend: float = 0.45
    confusion: float = 0.5
    noise: float = 3.0
    modality_offset: float = 0.8
    size_scale: float = 1.0
    # a modality gap that is not one constant vector (0: the project's scenes as before)
    gap_class: float = 0.0
    gap_instance: float = 0.0
    distortion: float = 0.0
    classes: str = "a"  # "a", "b" or a class-table YAML file (demo/class_file.py)

    def validate(self) -> ClassSet:
        """Check the options; return the class table they name (parsed once)."""
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if isinstance(v, float) and not math.isfinite(v):
                raise ConfigError(f"scene option {f.name} must be a finite number, not {v}.")
        if self.seed < 0:
            raise ConfigError(f"scene option seed must be >= 0 (numpy's seeds), not {self.seed}.")
        if self.extra_objects < 0:
            raise ConfigError(
                f"scene option extra_objects must be >= 0 (objects added to each room), "
                f"not {self.extra_objects}."
            )
        if self.size_scale <= 0 or self.confusion < 0:
            raise ConfigError("scene options size_scale must be > 0 and confusion >= 0.")
        if self.rooms < 1:
            raise ConfigError("scene option rooms must be >= 1.")
        if not 0.02 <= self.voxel_size <= 0.5:
            raise ConfigError("scene option voxel_size must be in [0.02, 0.5] metres.")
        if self.room_size < 2.0 or self.room_height < 1.5:
            raise ConfigError("scene option room_size must be >= 2 m and room_height >= 1.5 m.")
        if not 0.0 <= self.boundary_blend < 1.0:
            raise ConfigError("scene option boundary_blend must be in [0, 1).")
        if self.noise < 0 or self.modality_offset < 0 or self.names_per_voxel < 1:
            raise ConfigError(
                "scene options noise, modality_offset must be >= 0 and names_per_voxel >= 1."
            )
        if min(self.gap_class, self.gap_instance, self.distortion) < 0:
            raise ConfigError("scene options gap_class, gap_instance, distortion must be >= 0.")
        return class_set(self.classes)  # a shipped table, or a file that parses


@dataclass
class Scene:
    """The generated scene: the map, its taxonomy and suggested absence queries."""

    map: LatentMap
    taxonomy: dict[str, list[str]]
    absent: list[str]
    room_types: list[str]
    n_objects: int
    instance_ids: np.ndarray | None = None
    open_present: dict[str, str] = dataclasses.field(default_factory=dict)
    open_absent: list[str] = dataclasses.field(default_factory=list)
    class_table_sha256: str | None = None  # of the class-table file that built it
    #: appearance names nearer an absent label than their own (:mod:`.lookalikes`)
    absent_lookalikes: list[dict[str, Any]] = dataclasses.field(default_factory=list)


def make_scene(encoder: Any, options: SceneOptions | None = None, cache: Any = None) -> Scene:
    """Generate the scene with ``encoder`` (an :class:`~quash_plugins.core.interfaces.Encoder`).

    Deterministic for a given ``options.seed`` and encoder.
    """
    opts = options or SceneOptions()
    cs = opts.validate()
    rng = np.random.default_rng(opts.seed)
    CLASSES, ABSENT, ABSENT_FREE_TEXT = cs.classes, cs.absent, cs.absent_free_text
    label, inst, inst_class, room_types, n_objects = _layout(opts, rng, cs)
    cells = np.argwhere(label >= 0)
    labels = label[cells[:, 0], cells[:, 1], cells[:, 2]].astype(np.int64)
    cell_inst = inst[cells[:, 0], cells[:, 1], cells[:, 2]].astype(np.int64)
    E = voxel_embeddings(encoder, cs, opts, rng, inst, cells, labels, cell_inst, inst_class, cache)
    colors = np.asarray([c.color for c in CLASSES], np.int16)[labels]
    colors = np.clip(colors + rng.integers(-12, 13, colors.shape), 0, 255).astype(np.uint8)
    lmap = LatentMap(
        embeddings=E,
        kind="voxels",
        positions=(cells * opts.voxel_size).astype(np.float32),
        colors=colors,
        labels=labels,
        label_names=[c.label for c in CLASSES],
        voxel_size=float(opts.voxel_size),
        grid_index=cells.astype(np.int32),
        source={
            "adapter": "scene",
            "encoder_hint": f"{getattr(encoder, 'name', '?')} {E.shape[1]}",
            **_built_by(encoder),
            "seed": opts.seed,
        },
    )
    taxonomy = {c.label: list(c.language) for c in CLASSES}
    taxonomy.update({k: list(v) for k, v in ABSENT.items()})
    absent = [*ABSENT, *ABSENT_FREE_TEXT]
    log.info(
        "scene: %d rooms (%s), %d objects, %d voxels",
        opts.rooms,
        ", ".join(room_types),
        n_objects,
        len(labels),
    )
    present = [c.label for i, c in enumerate(CLASSES) if np.any(labels == i)]
    open_present, open_absent = open_queries(cs, present, opts.seed)
    lookalikes = scene_lookalikes(cs, present, encoder, cache)
    return Scene(
        lmap,
        taxonomy,
        absent,
        room_types,
        n_objects,
        cell_inst.astype(np.int32),
        open_present,
        open_absent,
        cs.sha256,
        lookalikes,
    )
