"""Logging a map, once, as static data: the 3D layers, the ceiling, the images, the view.

:class:`MapLogging` is the part of :class:`~quash_plugins.viewer.RerunLogger` that logs
the map (the logger's state is set up in ``RerunLogger.__init__``, in ``_rerun.py``),
with the drawing of a layer (boxes or points) that the query results reuse, and the
view's orientation: the up axis's view coordinates and the top-down eye.
"""

from __future__ import annotations

import hashlib
import weakref
from typing import Any

import numpy as np

from ..core.errors import QuashError
from ..core.types import LatentMap
from ._display import (
    UP_AXES,
    ceiling_items,
    colormap,
    display_indices,
    first_match_class,
    map_up,
    pca_colors,
    slugify,
)

#: Colour of matched items (RGB): a magenta no map palette is likely to use.
MATCH_COLOR = (255, 0, 200)
#: Items the presence check dropped (grey in the map view and the image masks).
REJECTED_COLOR = (150, 150, 150)


class MapLogging:
    """:meth:`log_map` and the drawing of a layer; a base of ``RerunLogger``."""

    def log_map(self, lmap: LatentMap) -> None:
        """Log the map once, as static data: ``world/map`` (``world/ceiling``) and
        ``images/<frame>/rgb``.

        Colours come from ``lmap.colors``, or from a PCA of the embeddings (fitted on a
        bounded sample, projected in blocks) when the map has none.

        A logger holds one map, as its recording does: the map's layers are static, so a
        second map would replace the first one's at every step. Logging the same map
        again (the same object, or the map read again: the same kind, items, geometry,
        colours and up axis) does nothing; another map raises :class:`QuashError` (log
        it to a recording and logger of its own).
        """
        if self._map_ref is not None and self._map_ref() is lmap:
            return
        key = self._map_fingerprint(lmap)
        if self._map_key is not None:
            if key != self._map_key:
                raise QuashError(
                    f"This RerunLogger already logged the map {self._map_name}; "
                    f"{_describe_map(lmap)} is another map. A recording holds one map: "
                    "world/map and the score geometry are static, so a second map would "
                    "replace the first one's at every step and draw the first one's "
                    "matches over it. Log each map to a recording of its own: a new "
                    "rerun.RecordingStream and RerunLogger per map (on the command line, "
                    "one --rrd file per map)."
                )
            self._map_ref = _weak(lmap)  # the same map, read again: nothing to log
            return
        rr, rec = self.rr, self.recording
        self._map_key, self._map_ref, self._map_name = key, _weak(lmap), _describe_map(lmap)
        self._notes = []
        self._configs = {}
        self._layers = {}
        self._eye = None
        self._has_world = lmap.positions is not None
        self._frames = []
        if self._has_world:
            display = display_indices(lmap.n, self.max_display_points)
            idx = np.arange(lmap.n, dtype=np.int64) if display is None else display
            if display is not None:
                self._notes.append(
                    f"The 3D layers show {len(idx):,} of {lmap.n:,} items (an even, deterministic "
                    "stride). This thinning is for display only; the query used every item."
                )
            self._voxel = float(lmap.voxel_size or 0.0)
            self._as_boxes = bool(
                lmap.kind == "voxels" and self._voxel and len(idx) <= self.max_boxes
            )
            pos = np.asarray(lmap.positions[idx], dtype=np.float32)
            if lmap.colors is not None:
                colors = np.asarray(lmap.colors[idx])
            else:
                colors = pca_colors(lmap, display)
                self._notes.append("The map has no RGB; it is coloured by a PCA of its embeddings.")
            up = map_up(self.up, lmap.source)
            ceiling = ceiling_items(pos, self._voxel, up) if up else None
            if up is not None:
                rec.log("world", _view_coordinates(rr, up), static=True)
            if ceiling is None:
                self._layers = {"": idx}
                rec.log("world/map", self._primitive(pos, 0.45, 0.5, colors=colors), static=True)
            else:
                below = ~ceiling
                self._layers = {"": idx[below], "ceiling": idx[ceiling]}
                rec.log(
                    "world/map",
                    self._primitive(pos[below], 0.45, 0.5, colors=colors[below]),
                    static=True,
                )
                rec.log(
                    "world/ceiling",
                    self._primitive(pos[ceiling], 0.45, 0.5, colors=colors[ceiling]),
                    static=True,
                )
                self._notes.append(
                    f"The ceiling ({int(ceiling.sum()):,} items at the top of the map) is "
                    "hidden so the rooms can be seen from above: show world/ceiling in the "
                    "blueprint panel."
                )
            below = pos if ceiling is None else pos[~ceiling]
            feet = _footprint(below, up)
            self._wide = bool(feet and feet[0] >= WIDE_FOOTPRINT * max(feet[1], 1e-6))
            self._eye = _top_down_eye(below, up, self._wide)
            rec.log("world/scores", self._score_context(), static=True)
        if lmap.kind == "pixels" and lmap.frames:
            rec.log(
                "images",
                rr.AnnotationContext(
                    [
                        (0, "background", (0, 0, 0, 0)),
                        (1, "match", (*MATCH_COLOR, 255)),
                        (2, "dropped by the presence check", (*REJECTED_COLOR, 255)),
                    ]
                ),
                static=True,
            )
            used: set[str] = set()
            for frame in lmap.frames[: self.max_frames]:
                name = slugify(str(frame.frame_id), "frame")
                while name in used:
                    name += "_"
                used.add(name)
                sl = slice(frame.offset, frame.offset + frame.size)
                if lmap.colors is not None:
                    rgb = lmap.colors[sl]
                else:
                    rgb = pca_colors(lmap, np.arange(sl.start, sl.stop))
                rec.log(
                    f"images/{name}/rgb",
                    rr.Image(np.ascontiguousarray(rgb.reshape(frame.height, frame.width, 3))),
                    static=True,
                )
                self._frames.append((name, frame))
            if len(lmap.frames) > self.max_frames:
                self._notes.append(
                    f"Only the first {self.max_frames} of {len(lmap.frames)} images are shown."
                )
        self._layout_changed()
        self._send_blueprint()

    def _map_fingerprint(self, lmap: LatentMap) -> tuple:
        """What the map's static layers are drawn from: two maps with the same
        fingerprint draw the same ``world/`` and ``images/`` layers."""
        frames = tuple((str(f.frame_id), f.height, f.width, f.offset) for f in lmap.frames or ())
        if lmap.colors is not None:
            colors: Any = _digest(lmap.colors)
        elif lmap.source:  # PCA colours of the embeddings: the same source, the same map
            source = sorted(lmap.source.items(), key=lambda kv: str(kv[0]))
            colors = ("pca", lmap.dim, bool(lmap.normalize), repr(source))
        else:  # an in-memory map with no colours and no source: only itself is itself
            colors = ("pca", object())
        positions = None if lmap.positions is None else _digest(lmap.positions)
        up = map_up(self.up, lmap.source)
        return (lmap.kind, lmap.n, lmap.voxel_size, up, frames, positions, colors)

    def _score_context(self) -> Any:
        """Class ``i`` of the score layers: the colormap at ``i / (score_classes - 1)``,
        labelled with that display score (``0.53``), ``(match)`` from the first class at
        or above the threshold's 0.5 (:func:`~._display.first_match_class`), which holds
        only display scores at or above 0.5 (:func:`~._display.score_classes`)."""
        rr = self.rr
        k = self.score_classes
        values = np.linspace(0.0, 1.0, k)
        rgb = colormap(values, self.colormap)
        first = first_match_class(k)
        return rr.AnnotationContext(
            [
                rr.AnnotationInfo(
                    id=i,
                    label=f"{v:.2f}" + (" (match)" if i >= first else ""),
                    color=(*map(int, rgb[i]), 255),
                )
                for i, v in enumerate(values)
            ]
        )

    def _primitive(
        self,
        pos: np.ndarray,
        box_scale: float,
        point_scale: float,
        colors: Any = None,
    ) -> Any:
        """Boxes3D for small voxel layers, Points3D otherwise.

        One box half size (``box_scale * voxel_size``) or point radius
        (``point_scale * voxel_size``; 0.5 is the voxel radius) serves every item;
        matches use a slightly larger scale than the map so they show through it.
        """
        rr = self.rr
        pos = np.asarray(pos, dtype=np.float32)
        if self._as_boxes:
            half = np.full((1, 3), self._voxel * box_scale, dtype=np.float32)
            return rr.Boxes3D(centers=pos, half_sizes=half, colors=colors, fill_mode="solid")
        radius = self._voxel * point_scale if self._voxel else None
        return rr.Points3D(pos, colors=colors, radii=radius)


def _weak(lmap: LatentMap) -> Any:
    """A weak reference to ``lmap``: a callable that returns it while it lives."""
    try:
        return weakref.ref(lmap)
    except TypeError:  # a map type without weak references: held, so its id stays its own
        return lambda: lmap


def _digest(values: Any) -> tuple:
    """Shape, dtype and a hash of an array's contents."""
    a = np.ascontiguousarray(values)
    h = hashlib.blake2b(a.data if a.size else b"", digest_size=16)
    return (a.shape, a.dtype.str, h.hexdigest())


def _describe_map(lmap: LatentMap) -> str:
    """``'scene.npz' (voxels, 51,234 items)``, for messages."""
    path = (lmap.source or {}).get("path")
    where = f"{str(path)!r} " if path else ""
    return f"{where}({lmap.kind}, {lmap.n:,} items)"


def _view_coordinates(rr: Any, up: str) -> Any:
    """Right-handed view coordinates with ``up`` as the up axis."""
    names = {
        "+z": "RIGHT_HAND_Z_UP",
        "-z": "RIGHT_HAND_Z_DOWN",
        "+y": "RIGHT_HAND_Y_UP",
        "-y": "RIGHT_HAND_Y_DOWN",
        "+x": "RIGHT_HAND_X_UP",
        "-x": "RIGHT_HAND_X_DOWN",
    }
    return getattr(rr.ViewCoordinates, names[up])


#: Footprints at least this many times longer than deep get the wide layout.
WIDE_FOOTPRINT = 2.5
#: tan(half the vertical field of view) of Rerun's 3D view (about 51 degrees).
_TAN_HALF_FOV = 0.48


def _footprint(pos: np.ndarray, up: str | None) -> tuple[float, float] | None:
    """(longer, shorter) horizontal extent of the map in metres."""
    if up is None or len(pos) == 0:
        return None
    axis, _ = UP_AXES[up]
    ext = sorted((float(np.ptp(pos[:, a])) for a in range(3) if a != axis), reverse=True)
    return ext[0], ext[1]


def _top_down_eye(pos: np.ndarray, up: str | None, wide: bool = False) -> tuple | None:
    """(eye position, look target, eye up) looking down on the map from above.

    The eye sits above the centre of the map's footprint, slightly behind it (so the
    view is not exactly along the up axis), far enough that the footprint fits a view
    of the layout's shape (about 3:1 for ``wide`` maps, 4:3 otherwise) at the height of
    the walls' tops, a storey closer to the eye than the floor.
    """
    if up is None or len(pos) == 0:
        return None
    axis, sign = UP_AXES[up]
    lo, hi = pos.min(axis=0).astype(np.float64), pos.max(axis=0).astype(np.float64)
    centre = (lo + hi) / 2
    flat = [a for a in range(3) if a != axis]
    longer, shorter = _footprint(pos, up) or (1.0, 1.0)
    aspect = 3.0 if wide else 1.3
    visible = max(shorter, longer / aspect, 1.0) / 0.85  # the view's height at the walls' tops
    target = centre.copy()
    target[axis] = lo[axis] if sign > 0 else hi[axis]
    eye = target.copy()
    eye[axis] += sign * (float(hi[axis] - lo[axis]) + visible / (2 * _TAN_HALF_FOV))
    # Step back along the shorter horizontal axis: the longer one runs across the screen.
    short_axis = flat[1] if hi[flat[0]] - lo[flat[0]] >= hi[flat[1]] - lo[flat[1]] else flat[0]
    eye[short_axis] -= 0.15 * visible
    up_vec = np.zeros(3)
    up_vec[axis] = sign
    return (tuple(map(float, eye)), tuple(map(float, target)), tuple(map(float, up_vec)))
