"""The layout of a proxy scene: rooms, their structure and their objects in a voxel grid.

:func:`_layout` fills a label volume and an instance volume for
:func:`~quash_plugins.demo.scene.make_scene`, drawing from the scene's generator in the
order the scene's seed pins (the same options and seed give the same volumes).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from .classes import SceneClass
    from .scene import ClassSet, SceneOptions


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
