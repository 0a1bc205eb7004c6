"""Log maps, query results and evaluation metrics to a Rerun recording."""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..core.errors import QuashError
from ..core.types import LatentMap, QueryResult
from ._display import (
    UP_AXES,
    ceiling_items,
    colormap,
    display_indices,
    pca_colors,
    score_classes,
    slugify,
    thin,
)
from ._document import queryset_markdown

log = logging.getLogger(__name__)

#: Colour of matched items (RGB): a magenta no map palette is likely to use.
MATCH_COLOR = (255, 0, 200)
#: Colour of instance boxes.
INSTANCE_COLOR = (255, 200, 0)
#: Colours of the configs' series in the evaluation plots (the same config has the same
#: colour in every plot); a colour-blind-safe qualitative palette (Okabe-Ito).
SERIES_COLORS = (
    (0, 114, 178),
    (230, 159, 0),
    (0, 158, 115),
    (204, 121, 167),
    (86, 180, 233),
    (213, 94, 0),
    (240, 228, 66),
    (0, 0, 0),
)


def import_rerun() -> Any:
    """Import ``rerun`` or raise a :class:`QuashError` naming the extra to install."""
    try:
        import rerun as rr
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise QuashError(
            'Rerun output needs the rerun SDK: pip install "quash-plugins[rerun]"'
        ) from exc
    return rr


class _ConfigState:
    """What was logged for one config."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.scores_logged = False


class RerunLogger:
    """Log maps and query results to an explicit Rerun recording.

    The logger writes only to ``recording`` (or to a new one it creates); it never uses
    or changes Rerun's global or thread-local recording.

    The map is logged once, as static data; each query adds only what is its own: the
    positions of its matches, one small class id per drawn item for the score colours,
    its instance boxes and its document. Results are grouped by config (one tab each in
    the blueprint) and placed on the ``query`` timeline by query index.

    Parameters
    ----------
    recording
        A :class:`rerun.RecordingStream` with its sinks already attached (``save``,
        ``connect_grpc``, ``serve_grpc``...). None creates ``rr.RecordingStream(app_id)``
        with Rerun's buffered sink; attach a sink through :attr:`recording`.
    app_id
        Application id of a recording created here.
    max_display_points
        Most items drawn per layer (map, mask, scores). Bigger maps are thinned for
        display only, with a deterministic even stride; queries always use every item.
    max_boxes
        Voxel maps with at most this many drawn voxels are drawn as boxes, bigger ones
        as points with the voxel radius.
    max_frames
        Most frames of a pixel map drawn under ``images/``.
    colormap
        Colormap name for scores (matplotlib's names; a built-in table otherwise).
    up
        The map's up axis (``"+z"``: VLMaps, the demo scene; ``"-y"``: camera frames...)
        or None when unknown. It orients the views (top-down by default) and finds the
        ceiling, which is logged apart and hidden so the rooms can be seen from above.
    score_classes
        Number of colour steps of the score layers (class ids of one annotation context).

    Examples
    --------
    >>> import rerun as rr  # doctest: +SKIP
    >>> rec = rr.RecordingStream("my-robot")  # doctest: +SKIP
    >>> rec.save("queries.rrd")  # doctest: +SKIP
    >>> logger = RerunLogger(rec)  # doctest: +SKIP
    >>> logger.log_map(lmap)  # doctest: +SKIP
    >>> for i, r in enumerate(results):  # doctest: +SKIP
    ...     logger.log_result(lmap, r, index=i)
    >>> logger.close()  # doctest: +SKIP
    """

    def __init__(
        self,
        recording: Any = None,
        app_id: str = "quash",
        *,
        max_display_points: int = 1_000_000,
        max_boxes: int = 50_000,
        max_frames: int = 8,
        colormap: str = "viridis",
        up: str | None = "+z",
        score_classes: int = 32,
    ) -> None:
        rr = import_rerun()
        self.rr = rr
        if recording is None:
            recording = rr.RecordingStream(app_id)
        elif not isinstance(recording, rr.RecordingStream):
            raise QuashError(
                f"RerunLogger needs a rerun.RecordingStream; got {type(recording).__name__}."
            )
        if up is not None and up not in UP_AXES:
            raise QuashError(f"RerunLogger: up must be one of {', '.join(UP_AXES)} or None.")
        if not 2 <= int(score_classes) <= 65535:
            raise QuashError("RerunLogger: score_classes must be in [2, 65535].")
        self.recording = recording
        self.max_display_points = int(max_display_points)
        self.max_boxes = int(max_boxes)
        self.max_frames = int(max_frames)
        self.colormap = colormap
        self.up = up
        self.score_classes = int(score_classes)
        self._map_key: int | None = None
        self._layers: dict[str, np.ndarray] = {}
        self._as_boxes = False
        self._voxel = 0.0
        self._eye: tuple | None = None
        self._wide = False
        self._frames: list[tuple[str, Any]] = []
        self._notes: list[str] = []
        self._has_world = False
        self._configs: dict[str, _ConfigState] = {}
        self._focus: str | None = None
        self._layout_sent: Any = None
        self._layout_dirty = False
        self._eval_steps: dict[str, int] = {}
        self._eval_series: set[str] = set()
        self._eval_metrics: dict[str, None] = {}
        self._eval_colors: dict[str, tuple[int, int, int]] = {}
        self._eval_last = -1
        self._has_summary = False

    # ------------------------------------------------------------------ map
    def log_map(self, lmap: LatentMap) -> None:
        """Log the map once, as static data: ``world/map`` (``world/ceiling``) and
        ``images/<frame>/rgb``.

        Colours come from ``lmap.colors``, or from a PCA of the embeddings (fitted on a
        bounded sample, projected in blocks) when the map has none.
        """
        rr, rec = self.rr, self.recording
        self._map_key = id(lmap)
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
            ceiling = ceiling_items(pos, self._voxel, self.up) if self.up else None
            if self.up is not None:
                rec.log("world", _view_coordinates(rr, self.up), static=True)
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
            feet = _footprint(below, self.up)
            self._wide = bool(feet and feet[0] >= WIDE_FOOTPRINT * max(feet[1], 1e-6))
            self._eye = _top_down_eye(below, self.up, self._wide)
            rec.log("world/scores", self._score_context(), static=True)
        if lmap.kind == "pixels" and lmap.frames:
            rec.log(
                "images",
                rr.AnnotationContext(
                    [(0, "background", (0, 0, 0, 0)), (1, "match", (*MATCH_COLOR, 255))]
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

    def _score_context(self) -> Any:
        """Class ``i`` of the score layers: the colormap at ``i / (score_classes - 1)``."""
        rr = self.rr
        k = self.score_classes
        rgb = colormap(np.linspace(0.0, 1.0, k), self.colormap)
        return rr.AnnotationContext(
            [rr.AnnotationInfo(id=i, color=(*map(int, rgb[i]), 255)) for i in range(k)]
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

    # ------------------------------------------------------------------ results
    def focus(self, config_name: str) -> None:
        """Open the viewer on this config's tab (default: the first config logged)."""
        self._focus = slugify(str(config_name), "config")
        self._layout_changed()

    def log_result(self, lmap: LatentMap, result: QueryResult, index: int) -> None:
        """Log one query's result at ``query = index`` on the ``query`` timeline.

        Per config (``result.config_name``): ``world/matches/<config>`` (the matched
        items), the class ids of ``world/scores/<config>``, ``world/instances/<config>``
        and the document ``queries/<config>``; for pixel maps
        ``images/<frame>/<config>/{mask,scores,instances}``. Each replaces the config's
        previous query, so scrubbing the timeline shows one query at a time per config.
        """
        rr, rec = self.rr, self.recording
        if self._map_key != id(lmap):
            self.log_map(lmap)
        if len(result.mask) != lmap.n:
            raise QuashError(
                f"Result for {result.query!r} has {len(result.mask)} items but the map has {lmap.n}."
            )
        index = int(index)
        name = str(result.config_name or "quash")
        c = slugify(name, "config")
        state = self._configs.setdefault(c, _ConfigState(name))
        rec.set_time("query", sequence=index)
        notes = list(self._notes)
        if self._has_world:
            self._log_world(lmap, result, c, state, notes)
        for fname, frame in self._frames:
            sl = slice(frame.offset, frame.offset + frame.size)
            hw = (frame.height, frame.width)
            seg = np.asarray(result.mask[sl]).reshape(hw).astype(np.uint8)
            base = f"images/{fname}/{c}"
            rec.log(f"{base}/mask", rr.SegmentationImage(seg, opacity=0.5))
            heat = colormap(np.asarray(result.display_scores[sl]), self.colormap)
            rec.log(f"{base}/scores", rr.Image(heat.reshape(*hw, 3)))
            self._log_pixel_instances(lmap, result, base, frame.frame_id)
        text = queryset_markdown(lmap, result, index, notes)
        rec.log(f"queries/{c}", rr.TextDocument(text, media_type=rr.MediaType.MARKDOWN))
        self._layout_changed()

    def _log_world(
        self, lmap: LatentMap, result: QueryResult, c: str, state: _ConfigState, notes: list[str]
    ) -> None:
        rr, rec = self.rr, self.recording
        matched = np.flatnonzero(result.mask)
        shown = thin(matched, self.max_display_points)
        if len(shown) < len(matched):
            notes.append(
                f"The mask layer shows {len(shown):,} of {len(matched):,} matched items "
                "(display only)."
            )
        rec.log(
            f"world/matches/{c}",
            self._primitive(lmap.positions[shown], 0.55, 0.6, colors=MATCH_COLOR),
        )
        # Scores: the geometry once per config (static), then one class id per item.
        scores = np.asarray(result.display_scores)
        archetype = rr.Boxes3D if self._as_boxes else rr.Points3D
        for layer, idx in self._layers.items():
            path = f"world/scores/{c}" + (f"/{layer}" if layer else "")
            if not state.scores_logged:
                rec.log(path, self._primitive(lmap.positions[idx], 0.45, 0.5), static=True)
            rec.log(
                path,
                archetype.from_fields(class_ids=score_classes(scores[idx], self.score_classes)),
            )
        state.scores_logged = True
        path = f"world/instances/{c}"
        insts = [i for i in result.instances if i.frame_id is None]
        if not insts:
            rec.log(path, rr.Clear(recursive=True))
            return
        lo = np.array([i.bbox_min for i in insts], dtype=np.float32).reshape(-1, 3)
        hi = np.array([i.bbox_max for i in insts], dtype=np.float32).reshape(-1, 3)
        pad = 0.5 * self._voxel
        rec.log(
            path,
            rr.Boxes3D(
                centers=(lo + hi) / 2,
                half_sizes=(hi - lo) / 2 + pad,
                colors=INSTANCE_COLOR,
                labels=[f"{result.query} #{i.id} ({i.size}, {i.mean_score:.2f})" for i in insts],
            ),
        )
        cents = np.array([i.centroid for i in insts], dtype=np.float32).reshape(-1, 3)
        rec.log(f"{path}/centroids", rr.Points3D(cents, colors=INSTANCE_COLOR))

    def _log_pixel_instances(
        self, lmap: LatentMap, result: QueryResult, base: str, frame_id: str
    ) -> None:
        """Labelled 2D boxes for a pixel map's instances (pixel coordinates x=col, y=row)."""
        rr, rec = self.rr, self.recording
        path = f"{base}/instances"
        insts = [i for i in result.instances if i.frame_id == frame_id]
        if not insts or lmap.positions is not None:
            rec.log(path, rr.Clear(recursive=False))
            return
        lo = np.array([i.bbox_min for i in insts], dtype=np.float32).reshape(-1, 3)[:, :2]
        hi = np.array([i.bbox_max for i in insts], dtype=np.float32).reshape(-1, 3)[:, :2]
        rec.log(
            path,
            rr.Boxes2D(
                mins=lo,
                sizes=hi - lo + 1.0,
                colors=INSTANCE_COLOR,
                labels=[f"{result.query} #{i.id} ({i.size})" for i in insts],
            ),
        )

    def log_summary(self, markdown: str) -> None:
        """A static Markdown document (e.g. a comparison table) shown beside the metrics."""
        rr = self.rr
        self.recording.log(
            "summary", rr.TextDocument(markdown, media_type=rr.MediaType.MARKDOWN), static=True
        )
        self._has_summary = True
        self._layout_changed()

    # ------------------------------------------------------------------ eval
    def log_eval_scalars(
        self, config_name: str, metrics: dict[str, Any], step_or_query: int | str
    ) -> None:
        """Log evaluation metrics as scalars under ``eval/<metric>/<config>``.

        Parameters
        ----------
        config_name
            The method config's name; one series per config and metric.
        metrics
            ``{"precision": p, "recall": r, "f1": f, "iou": i, ...}``; every finite
            number is logged, other values are skipped. Grouping by metric first gives
            one plot per metric that compares the configs.
        step_or_query
            Position on the ``query`` timeline: an int, or a query string mapped to
            0, 1, 2... in order of first appearance (the same query string gets the
            same step for every config).
        """
        rr, rec = self.rr, self.recording
        if isinstance(step_or_query, str):
            step = self._eval_steps.setdefault(step_or_query, len(self._eval_steps))
        else:
            step = int(step_or_query)
        rec.set_time("query", sequence=step)
        cfg = slugify(str(config_name), "config")
        for key, value in metrics.items():
            try:
                v = float(value)
            except (TypeError, ValueError):
                continue
            if not math.isfinite(v):
                continue
            metric = slugify(str(key), "metric")
            path = f"eval/{metric}/{cfg}"
            if path not in self._eval_series:
                self._eval_series.add(path)
                color = self._eval_colors.setdefault(
                    cfg, SERIES_COLORS[len(self._eval_colors) % len(SERIES_COLORS)]
                )
                name = str(config_name)
                rec.log(path, rr.SeriesLines(names=name, colors=color), static=True)
                rec.log(
                    path, rr.SeriesPoints(names=name, colors=color, marker_sizes=3.0), static=True
                )
            rec.log(path, rr.Scalars([v]))
            self._eval_metrics.setdefault(metric, None)
            self._eval_last = max(self._eval_last, step)
        self._layout_changed()

    def log_evaluation(
        self,
        configs: Sequence[dict[str, Any]],
        queries: Sequence[str],
        summary_markdown: str | None = None,
        metrics: Sequence[str] = ("f1", "precision", "recall", "iou"),
    ) -> None:
        """Log an evaluation report: per-query metrics of every config, and a summary.

        ``configs`` is the report's JSON list (``[{"name", "per_query": {query: {...}}}]``,
        :class:`quash_plugins.evaluation.report.EvalReport`); query ``i`` of ``queries``
        goes to step ``i`` of the ``query`` timeline, where :meth:`log_result` puts its
        result, so the plots line up with the queries shown in the 3D views.
        """
        for c in configs:
            per_query = c.get("per_query") or {}
            for i, q in enumerate(queries):
                row = per_query.get(q)
                if row:
                    self.log_eval_scalars(c["name"], {m: row.get(m) for m in metrics}, i)
        if summary_markdown:
            self.log_summary(summary_markdown)

    # ------------------------------------------------------------------ lifecycle
    def _layout_changed(self) -> None:
        """Note that the blueprint may be out of date; :meth:`flush` sends it."""
        self._layout_dirty = True

    def _send_blueprint(self) -> None:
        """Send the blueprint for what is logged now, unless the same one was sent.

        Called by :meth:`log_map` (a live viewer gets its layout with the map) and by
        :meth:`flush`; blueprints are not re-sent per query, which kept recordings small.
        """
        from ._blueprint import Layout, build_blueprint

        self._layout_dirty = False
        layout = Layout(
            has_world=self._has_world,
            has_ceiling="ceiling" in self._layers,
            eye=self._eye,
            wide=self._wide,
            configs=tuple((c, st.name) for c, st in self._configs.items()),
            frames=tuple(n for n, _ in self._frames),
            metrics=tuple(self._eval_metrics),
            eval_steps=self._eval_last + 1,
            has_summary=self._has_summary,
            focus=self._focus,
        )
        if layout == self._layout_sent:
            return
        self._layout_sent = layout
        self.recording.send_blueprint(build_blueprint(layout), make_active=True, make_default=True)

    def flush(self, timeout_s: float | None = None) -> None:
        """Wait until everything logged so far reached the recording's sinks.

        With ``timeout_s`` Rerun raises when the sinks have not taken everything by then.
        """
        if self._layout_dirty:
            self._send_blueprint()
        if timeout_s is None:
            self.recording.flush()
        else:
            self.recording.flush(timeout_sec=float(timeout_s))

    def close(self) -> None:
        """Flush. A recording passed in by the caller stays open and keeps its sinks."""
        self.flush()

    def __enter__(self) -> RerunLogger:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


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
