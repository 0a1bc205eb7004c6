"""A 3D indoor proxy scene whose voxel embeddings come from a real text encoder.

Rooms in a row share walls; each has a floor, walls, a ceiling, a door, a window and
the furniture of its room type. Every voxel's embedding is the normalised mean of a few
"appearance" names of its object's class, blended with a neighbouring object's embedding
at boundaries, plus Gaussian noise and one constant "modality offset" (image embeddings
of real maps sit apart from the text embeddings that query them). The taxonomy YAML
written next to the map holds only the disjoint "language" names, so no method embeds
the strings that built the voxels.

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
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import ConfigError
from ..core.interfaces import plugin_name
from ..core.types import LatentMap
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


def _class_index(cs: ClassSet) -> dict[str, int]:
    return {c.label: i for i, c in enumerate(cs.classes)}


def _layout(opts: SceneOptions, rng: np.random.Generator, cs: ClassSet):
    """Fill a label volume and an instance volume; return them and the instance classes."""
    vs = opts.voxel_size
    n_room = int(round(opts.room_size / vs))
    nx, ny, nz = n_room * opts.rooms + 1, n_room + 1, int(round(opts.room_height / vs)) + 1
    label = np.full((nx, ny, nz), -1, np.int16)
    inst = np.full((nx, ny, nz), -1, np.int32)
    CLASSES, ROOM_TYPES, SUPPORTS = cs.classes, cs.room_types, cs.supports
    idx = _class_index(cs)
    inst_class: list[int] = []

    def new_instance(cls: str) -> int:
        inst_class.append(idx[cls])
        return len(inst_class) - 1

    def put(sl: tuple, cls: str, i: int, only_existing: bool = False) -> None:
        if only_existing:
            m = label[sl] >= 0
            label[sl][m], inst[sl][m] = idx[cls], i
        else:
            label[sl], inst[sl] = idx[cls], i

    types = list(ROOM_TYPES)
    room_types = [
        types[(r + int(rng.integers(len(types)))) % len(types)] if r >= len(types) else types[r]
        for r in range(opts.rooms)
    ]
    for r in range(opts.rooms):
        x0, x1 = r * n_room, (r + 1) * n_room
        put((slice(x0, x1 + 1), slice(0, ny), 0), "floor", new_instance("floor"))
        put((slice(x0, x1 + 1), slice(0, ny), nz - 1), "ceiling", new_instance("ceiling"))
        w = new_instance("wall")
        for sl in (
            (x0, slice(0, ny)),
            (x1, slice(0, ny)),
            (slice(x0, x1 + 1), 0),
            (slice(x0, x1 + 1), ny - 1),
        ):
            put((*sl, slice(1, nz - 1)), "wall", w)

    def size_cells(c: SceneClass) -> tuple[int, int, int]:
        j = rng.uniform(0.8, 1.2, 3) * opts.size_scale
        sx, sy, sz = (max(1, int(round(s * f / vs))) for s, f in zip(c.size, j))
        # an object longer than the room (a car in a 4.5 m room) is cut to fit inside its
        # walls: its slices ran into the next room, or past the last one's end
        return min(sx, n_room - 2), min(sy, n_room - 2), sz

    n_objects = 0
    for r, rtype in enumerate(room_types):
        x0, x1 = r * n_room, (r + 1) * n_room
        names = ["door", "window", *ROOM_TYPES[rtype]]
        extra = rng.choice(ROOM_TYPES[rtype], size=opts.extra_objects, replace=True)
        names += [str(e) for e in extra]
        occupied: list[tuple[int, int, int, int]] = []
        supports: list[tuple[int, int, int, int, int]] = []
        wall_slots: list[tuple[int, int, int]] = []
        for name in sorted(
            names, key=lambda n: ("structure", "floor", "wall", "top").index(CLASSES[idx[n]].place)
        ):
            c = CLASSES[idx[name]]
            sx, sy, sz = size_cells(c)
            i = new_instance(name)
            placed = False
            for _ in range(40):
                if c.place == "floor":
                    if c.size[2] < vs * 1.5:  # flat (rug): replaces floor voxels
                        ax = int(rng.integers(x0 + 2, max(x0 + 3, x1 - sx - 1)))
                        ay = int(rng.integers(2, max(3, ny - sy - 2)))
                        put((slice(ax, ax + sx), slice(ay, ay + sy), 0), name, i)
                        placed = True
                        break
                    if rng.random() < 0.5:
                        sx, sy = sy, sx
                    ax = int(rng.integers(x0 + 1, max(x0 + 2, x1 - sx)))
                    ay = int(rng.integers(1, max(2, ny - 1 - sy)))
                    rect = (ax, ay, ax + sx, ay + sy)
                    if any(
                        rect[0] < o[2] and o[0] < rect[2] and rect[1] < o[3] and o[1] < rect[3]
                        for o in occupied
                    ):
                        continue
                    occupied.append(rect)
                    zt = min(nz - 2, sz)
                    sl = (slice(ax, ax + sx), slice(ay, ay + sy), slice(1, zt + 1))
                    block = np.zeros((sx, sy, zt), bool)
                    block[[0, -1], :, :] = block[:, [0, -1], :] = True
                    block[:, :, -1] = True
                    label[sl][block], inst[sl][block] = idx[name], i
                    if name in SUPPORTS:
                        supports.append((ax, ay, ax + sx, ay + sy, zt + 1))
                    placed = True
                    break
                if c.place == "wall":
                    side = int(rng.integers(4))
                    sz = min(sz, nz - 3)
                    a = int(rng.integers(1, max(2, n_room - sx)))
                    zb = 1 if name in cs.wall_bottom else int(rng.integers(1, max(2, nz - 1 - sz)))
                    if name in cs.wall_top:
                        zb = max(1, nz - 1 - sz)
                    if any(
                        s == side and abs(a - b) < sx and abs(zb - z) < sz for s, b, z in wall_slots
                    ):
                        continue
                    wall_slots.append((side, a, zb))
                    zs = slice(zb, min(nz - 1, zb + sz))
                    if side == 0:
                        sls = [(x0, slice(a, a + sx), zs), (x0 + 1, slice(a, a + sx), zs)]
                    elif side == 1:
                        sls = [(x1, slice(a, a + sx), zs), (x1 - 1, slice(a, a + sx), zs)]
                    elif side == 2:
                        sls = [
                            (slice(x0 + a, x0 + a + sx), 0, zs),
                            (slice(x0 + a, x0 + a + sx), 1, zs),
                        ]
                    else:
                        sls = [
                            (slice(x0 + a, x0 + a + sx), ny - 1, zs),
                            (slice(x0 + a, x0 + a + sx), ny - 2, zs),
                        ]
                    put(sls[0], name, i)
                    put(sls[1], name, i)
                    placed = True
                    break
                if c.place == "top" and supports:
                    bx0, by0, bx1, by1, bz = supports[int(rng.integers(len(supports)))]
                    sx, sy = min(sx, bx1 - bx0), min(sy, by1 - by0)
                    ax = int(rng.integers(bx0, max(bx0 + 1, bx1 - sx + 1)))
                    ay = int(rng.integers(by0, max(by0 + 1, by1 - sy + 1)))
                    zt = min(nz - 2, bz + sz)
                    put((slice(ax, ax + sx), slice(ay, ay + sy), slice(bz, zt)), name, i)
                    placed = True
                    break
            if placed:
                n_objects += 1
            else:
                inst_class.pop()
    return label, inst, np.asarray(inst_class, np.int64), room_types, n_objects


_OFFSETS = [
    (dx, dy, dz)
    for dx in (-1, 0, 1)
    for dy in (-1, 0, 1)
    for dz in (-1, 0, 1)
    if (dx, dy, dz) != (0, 0, 0)
]


def _boundary_partner(inst: np.ndarray, cells: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """For each occupied cell, a neighbouring instance of another class (or -1)."""
    own = inst[cells[:, 0], cells[:, 1], cells[:, 2]]
    partner = np.full(len(cells), -1, np.int64)
    shape = np.asarray(inst.shape)
    for k in rng.permutation(len(_OFFSETS)):
        nb = cells + np.asarray(_OFFSETS[k])
        ok = ((nb >= 0) & (nb < shape)).all(axis=1)
        other = np.full(len(cells), -1, np.int64)
        other[ok] = inst[nb[ok, 0], nb[ok, 1], nb[ok, 2]]
        take = (partner < 0) & (other >= 0) & (other != own)
        partner[take] = other[take]
    return partner


def make_scene(encoder: Any, options: SceneOptions | None = None, cache: Any = None) -> Scene:
    """Generate the scene with ``encoder`` (an :class:`~quash_plugins.core.interfaces.Encoder`).

    Deterministic for a given ``options.seed`` and encoder.
    """
    from ..core.text import encode_texts

    opts = options or SceneOptions()
    cs = opts.validate()
    rng = np.random.default_rng(opts.seed)
    CLASSES, ABSENT, ABSENT_FREE_TEXT = cs.classes, cs.absent, cs.absent_free_text
    label, inst, inst_class, room_types, n_objects = _layout(opts, rng, cs)
    cells = np.argwhere(label >= 0)
    labels = label[cells[:, 0], cells[:, 1], cells[:, 2]].astype(np.int64)
    cell_inst = inst[cells[:, 0], cells[:, 1], cells[:, 2]].astype(np.int64)
    # one embedding per distinct appearance name, each encoded once
    names = sorted({n for c in CLASSES for n in c.appearance})
    name_row = {n: i for i, n in enumerate(names)}
    A = encode_texts(encoder, names, cache)
    D = A.shape[1]
    # every object instance mixes a few of its class's appearance names
    V = np.zeros((len(inst_class), D), np.float32)
    for i, ci in enumerate(inst_class):
        app = CLASSES[ci].appearance
        k = min(len(app), opts.names_per_voxel)
        pick = rng.choice(len(app), size=k, replace=False)
        w = rng.dirichlet(np.ones(k) * 2.0)
        v = (w[:, None] * A[[name_row[app[j]] for j in pick]]).sum(axis=0)
        V[i] = v / np.linalg.norm(v)
    E = V[cell_inst].copy()
    partner = _boundary_partner(inst, cells, rng)
    mixed = partner >= 0
    if opts.boundary_blend > 0 and mixed.any():
        wb = rng.uniform(0.0, opts.boundary_blend, int(mixed.sum())).astype(np.float32)
        E[mixed] = (1 - wb[:, None]) * E[mixed] + wb[:, None] * V[partner[mixed]]
    if opts.confusion > 0:  # semantic noise: every voxel also resembles some other object
        other = rng.integers(len(V), size=len(E))
        wc = rng.uniform(0.0, opts.confusion, len(E)).astype(np.float32) ** 2
        E = (1 - wc[:, None]) * E + wc[:, None] * V[other]
    E /= np.linalg.norm(E, axis=1, keepdims=True)
    if opts.noise > 0:
        E += rng.standard_normal(E.shape).astype(np.float32) * (opts.noise / np.sqrt(D))
    offset = rng.standard_normal(D).astype(np.float32)
    E = E / np.linalg.norm(
        E, axis=1, keepdims=True
    ) + opts.modality_offset * offset / np.linalg.norm(offset)
    E = _gap(E, labels, cell_inst, len(CLASSES), len(inst_class), opts)
    E = (E / np.linalg.norm(E, axis=1, keepdims=True)).astype(np.float32)
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
            "encoder_hint": f"{getattr(encoder, 'name', '?')} {D}",
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


def _built_by(encoder: Any) -> dict[str, str]:
    """The map's record of the encoder that built it (``LatentMap.source``), so that a
    query with another encoder is warned about, naming the parameters to write
    (``encoder_params``: :func:`~quash_plugins.adapters._npz.encoder_params` as JSON)."""
    import json

    from ..core.encoder_record import encoder_params

    fingerprint = getattr(encoder, "fingerprint", None)
    if not callable(fingerprint):
        return {}
    # The name a config writes (a factory entry point may build a class of another name).
    record = {"encoder": plugin_name(encoder), "encoder_fingerprint": fingerprint()}
    params = encoder_params(encoder)
    if params is not None:
        record["encoder_params"] = json.dumps(params, allow_nan=False)
    return record


def _unit_rows(rng: np.random.Generator, n: int, d: int) -> np.ndarray:
    v = rng.standard_normal((n, d)).astype(np.float32)
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _gap(E, labels, cell_inst, n_classes, n_inst, opts: SceneOptions) -> np.ndarray:
    """A modality gap that is not one constant vector.

    Applied after the shared offset: a random linear distortion ``E (I + d G / sqrt(D))``
    (``distortion``), one random direction per class of norm ``gap_class`` and one per
    object instance of norm ``gap_instance``. Drawn from its own generator (seeded from
    the scene's seed), so a scene with all three at 0 is byte for byte what it was.
    """
    if not (opts.gap_class or opts.gap_instance or opts.distortion):
        return E
    rng = np.random.default_rng([opts.seed, 12])
    D = E.shape[1]
    if opts.distortion:
        G = rng.standard_normal((D, D)).astype(np.float32) / np.sqrt(D)
        E = E + opts.distortion * (E @ G)
    if opts.gap_class:
        E = E + opts.gap_class * _unit_rows(rng, n_classes, D)[labels]
    if opts.gap_instance:
        E = E + opts.gap_instance * _unit_rows(rng, n_inst, D)[cell_inst]
    return E


_TAXONOMY_HEAD = "# language names only: disjoint from the appearance names that built the voxels\n"


def scene_paths(out: str | Path) -> dict[str, Path]:
    """The files :func:`write_scene` writes for ``OUT.npz``."""
    out = Path(out)
    stem = out.with_suffix("")
    return {
        "map": out,
        "taxonomy": Path(f"{stem}.taxonomy.yaml"),
        "queries": Path(f"{stem}.queries.yaml"),
        "open_queries": Path(f"{stem}.open-queries.yaml"),
    }


def is_scene_file(path: str | Path) -> bool:
    """True when ``path`` is one of the files a previous :func:`write_scene` wrote.

    The queries file is a mapping with ``present``, ``absent`` and ``room_types``; the
    taxonomy starts with the scene's comment; the map is an NPZ map whose queries file
    is such a record. These may be replaced without ``--force``; nothing else may.
    """
    import zipfile

    p = Path(path)
    try:
        if p.name.endswith(".queries.yaml"):
            from ..core.yaml_files import load_yaml

            data, _ = load_yaml(p)
            return isinstance(data, dict) and {"present", "absent", "room_types"} <= set(data)
        if p.name.endswith(".open-queries.yaml"):
            from ..core.yaml_files import load_yaml

            data, _ = load_yaml(p)
            return isinstance(data, dict) and {"present", "absent", "kind"} <= set(data)
        if p.name.endswith(".taxonomy.yaml"):
            with open(p, encoding="utf-8") as f:
                return f.readline() == _TAXONOMY_HEAD
        if p.suffix == ".npz":
            with zipfile.ZipFile(p) as zf:
                if "embeddings.npy" not in zf.namelist():
                    return False
            return is_scene_file(scene_paths(p)["queries"])
    except (OSError, UnicodeDecodeError, zipfile.BadZipFile, ConfigError):
        return False
    return False


def write_scene(
    scene: Scene, out: str | Path, options: SceneOptions | None = None
) -> dict[str, Path]:
    """Write ``OUT.npz``, ``OUT.taxonomy.yaml`` and ``OUT.queries.yaml``; return the paths."""
    import yaml

    from ..adapters import write_npz_map
    from ..core.atomic import atomic_write

    out = Path(out)
    if out.suffix != ".npz":
        raise ConfigError(f"{out}: the scene is written as our NPZ format; use a .npz name.")
    out.parent.mkdir(parents=True, exist_ok=True)
    write_npz_map(scene.map, out)
    paths = scene_paths(out)
    tax, queries = paths["taxonomy"], paths["queries"]
    head = _TAXONOMY_HEAD
    with atomic_write(tax, suffix=".yaml") as tmp:
        Path(tmp).write_text(head + yaml.safe_dump(scene.taxonomy, sort_keys=False), "utf-8")
    present = sorted({scene.map.label_names[i] for i in np.unique(scene.map.labels)})
    info = {
        "present": present,
        "absent": scene.absent,
        "room_types": scene.room_types,
        "options": dataclasses.asdict(options) if options else None,
    }
    if scene.class_table_sha256:  # which file content built it
        info["class_table_sha256"] = scene.class_table_sha256
    if scene.absent_lookalikes:  # appearance names that read as an absent label
        info["absent_lookalikes"] = scene.absent_lookalikes
    with atomic_write(queries, suffix=".yaml") as tmp:
        Path(tmp).write_text(yaml.safe_dump(info, sort_keys=False), "utf-8")
    open_info = {
        "kind": "open-vocabulary queries: sub-class names and free text, with their label",
        "present": dict(scene.open_present),
        "absent": list(scene.open_absent),
    }
    if scene.absent_lookalikes:
        open_info["absent_lookalikes"] = scene.absent_lookalikes
    with atomic_write(paths["open_queries"], suffix=".yaml") as tmp:
        Path(tmp).write_text(yaml.safe_dump(open_info, sort_keys=False), "utf-8")
    return {**paths}
