"""Log maps, query results and evaluation metrics to a Rerun recording."""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np

from ..core.errors import QuashError
from ..core.types import LatentMap, QueryResult
from ._display import colormap, display_indices, pca_colors, slugify, thin
from ._document import queryset_markdown

log = logging.getLogger(__name__)

#: Colour of matched items (RGB): a magenta no map palette is likely to use.
MATCH_COLOR = (255, 0, 200)
#: Colour of instance boxes.
INSTANCE_COLOR = (255, 200, 0)


def import_rerun() -> Any:
    """Import ``rerun`` or raise a :class:`QuashError` naming the extra to install."""
    try:
        import rerun as rr
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise QuashError(
            'Rerun output needs the rerun SDK: pip install "quash-plugins[rerun]"'
        ) from exc
    return rr


class RerunLogger:
    """Log maps and query results to an explicit Rerun recording.

    The logger writes only to ``recording`` (or to a new one it creates); it never uses
    or changes Rerun's global or thread-local recording.

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
    ) -> None:
        rr = import_rerun()
        self.rr = rr
        if recording is None:
            recording = rr.RecordingStream(app_id)
        elif not isinstance(recording, rr.RecordingStream):
            raise QuashError(
                f"RerunLogger needs a rerun.RecordingStream; got {type(recording).__name__}."
            )
        self.recording = recording
        self.max_display_points = int(max_display_points)
        self.max_boxes = int(max_boxes)
        self.max_frames = int(max_frames)
        self.colormap = colormap
        self._map_key: int | None = None
        self._display: np.ndarray | None = None
        self._as_boxes = False
        self._frames: list[tuple[str, Any]] = []
        self._notes: list[str] = []
        self._has_world = False
        self._has_eval = False
        self._layout_sent: tuple | None = None
        self._slugs: dict[int, str] = {}
        self._current: str | None = None
        self._eval_steps: dict[str, int] = {}
        self._eval_series: set[str] = set()

    # ------------------------------------------------------------------ map
    def log_map(self, lmap: LatentMap) -> None:
        """Log the map once, as static data: ``world/map`` and ``images/<frame>/rgb``.

        Colours come from ``lmap.colors``, or from a PCA of the embeddings (fitted on a
        bounded sample, projected in blocks) when the map has none.
        """
        rr, rec = self.rr, self.recording
        self._map_key = id(lmap)
        self._notes = []
        self._slugs = {}
        self._current = None
        self._has_world = lmap.positions is not None
        self._frames = []
        if self._has_world:
            self._display = display_indices(lmap.n, self.max_display_points)
            shown = lmap.n if self._display is None else len(self._display)
            if self._display is not None:
                self._notes.append(
                    f"The 3D layers show {shown:,} of {lmap.n:,} items (an even, deterministic "
                    "stride). This thinning is for display only; the query used every item."
                )
            self._as_boxes = bool(
                lmap.kind == "voxels" and lmap.voxel_size and shown <= self.max_boxes
            )
            pos = lmap.positions if self._display is None else lmap.positions[self._display]
            if lmap.colors is not None:
                colors = lmap.colors if self._display is None else lmap.colors[self._display]
            else:
                colors = pca_colors(lmap, self._display)
                self._notes.append("The map has no RGB; it is coloured by a PCA of its embeddings.")
            rec.log("world/map", self._primitive(lmap, pos, colors, 0.45, 0.5), static=True)
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
        self._send_blueprint()

    def _primitive(
        self, lmap: LatentMap, pos: np.ndarray, colors: Any, box_scale: float, point_scale: float
    ) -> Any:
        """Boxes3D for small voxel layers, Points3D otherwise.

        Box half sizes are ``box_scale * voxel_size`` and point radii
        ``point_scale * voxel_size`` (0.5: the voxel radius); matches use a slightly
        larger scale than the map so they show through it.
        """
        rr = self.rr
        pos = np.asarray(pos, dtype=np.float32)
        if self._as_boxes:
            half = np.full(3, float(lmap.voxel_size) * box_scale, dtype=np.float32)
            return rr.Boxes3D(
                centers=pos,
                half_sizes=np.broadcast_to(half, pos.shape),
                colors=colors,
                fill_mode="solid",
            )
        radius = float(lmap.voxel_size) * point_scale if lmap.voxel_size else None
        return rr.Points3D(pos, colors=colors, radii=radius)

    # ------------------------------------------------------------------ results
    def log_result(self, lmap: LatentMap, result: QueryResult, index: int) -> None:
        """Log one query's result at ``query = index`` on the ``query`` timeline.

        Writes ``world/queries/<slug>/{mask,scores,instances}``, ``queries/<slug>/queryset``
        and, for pixel maps, ``images/<frame>/{mask,scores}``. The previous query's
        entities are cleared at this index, so scrubbing shows one query at a time.
        """
        rr, rec = self.rr, self.recording
        if self._map_key != id(lmap):
            self.log_map(lmap)
        if len(result.mask) != lmap.n:
            raise QuashError(
                f"Result for {result.query!r} has {len(result.mask)} items but the map has {lmap.n}."
            )
        index = int(index)
        slug = self._slug_for(result.query, index)
        rec.set_time("query", sequence=index)
        if self._current is not None and self._current != slug:
            if self._has_world:
                rec.log(f"world/queries/{self._current}", rr.Clear(recursive=True))
            rec.log(f"queries/{self._current}", rr.Clear(recursive=True))
        self._current = slug
        notes = list(self._notes)
        if self._has_world:
            self._log_world(lmap, result, slug, notes)
        for name, frame in self._frames:
            sl = slice(frame.offset, frame.offset + frame.size)
            hw = (frame.height, frame.width)
            seg = np.asarray(result.mask[sl]).reshape(hw).astype(np.uint8)
            rec.log(f"images/{name}/mask", rr.SegmentationImage(seg, opacity=0.5))
            heat = colormap(np.asarray(result.display_scores[sl]), self.colormap)
            rec.log(f"images/{name}/scores", rr.Image(heat.reshape(*hw, 3)))
            self._log_pixel_instances(lmap, result, name, frame.frame_id)
        text = queryset_markdown(lmap, result, index, notes)
        rec.log(f"queries/{slug}/queryset", rr.TextDocument(text, media_type=rr.MediaType.MARKDOWN))
        self._send_blueprint()

    def _log_world(self, lmap: LatentMap, result: QueryResult, slug: str, notes: list[str]) -> None:
        rr, rec = self.rr, self.recording
        base = f"world/queries/{slug}"
        matched = np.flatnonzero(result.mask)
        shown = thin(matched, self.max_display_points)
        if len(shown) < len(matched):
            notes.append(
                f"The mask layer shows {len(shown):,} of {len(matched):,} matched items "
                "(display only)."
            )
        rec.log(
            f"{base}/mask", self._primitive(lmap, lmap.positions[shown], MATCH_COLOR, 0.55, 0.6)
        )
        idx = self._display
        pos = lmap.positions if idx is None else lmap.positions[idx]
        values = result.display_scores if idx is None else result.display_scores[idx]
        rec.log(
            f"{base}/scores", self._primitive(lmap, pos, colormap(values, self.colormap), 0.45, 0.5)
        )
        insts = [i for i in result.instances if i.frame_id is None]
        if insts:
            lo = np.array([i.bbox_min for i in insts], dtype=np.float32).reshape(-1, 3)
            hi = np.array([i.bbox_max for i in insts], dtype=np.float32).reshape(-1, 3)
            pad = 0.5 * float(lmap.voxel_size or 0.0)
            rec.log(
                f"{base}/instances",
                rr.Boxes3D(
                    centers=(lo + hi) / 2,
                    half_sizes=(hi - lo) / 2 + pad,
                    colors=INSTANCE_COLOR,
                    labels=[
                        f"{result.query} #{i.id} ({i.size}, {i.mean_score:.2f})" for i in insts
                    ],
                ),
            )
            cents = np.array([i.centroid for i in insts], dtype=np.float32).reshape(-1, 3)
            rec.log(f"{base}/instances/centroids", rr.Points3D(cents, colors=INSTANCE_COLOR))

    def _log_pixel_instances(
        self, lmap: LatentMap, result: QueryResult, name: str, frame_id: str
    ) -> None:
        """Labelled 2D boxes for a pixel map's instances (pixel coordinates x=col, y=row)."""
        rr, rec = self.rr, self.recording
        path = f"images/{name}/instances"
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

    def _slug_for(self, query: str, index: int) -> str:
        if index in self._slugs:
            return self._slugs[index]
        base = slugify(query, f"q{index}")
        slug = base
        taken = set(self._slugs.values())
        while slug in taken:
            slug = f"{base}_{index}"
            base = slug
        self._slugs[index] = slug
        return slug

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
            number is logged, other values are skipped. Grouping by metric first lets
            one plot compare configs.
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
            path = f"eval/{slugify(str(key), 'metric')}/{cfg}"
            if path not in self._eval_series:
                self._eval_series.add(path)
                rec.log(path, rr.SeriesLines(names=f"{config_name} {key}"), static=True)
            rec.log(path, rr.Scalars([v]))
        if not self._has_eval:
            self._has_eval = True
            self._send_blueprint()

    # ------------------------------------------------------------------ lifecycle
    def _send_blueprint(self) -> None:
        from ._blueprint import build_blueprint

        slugs = tuple(self._slugs[i] for i in sorted(self._slugs))
        layout = (self._has_world, slugs, tuple(n for n, _ in self._frames), self._has_eval)
        if layout == self._layout_sent:
            return
        self._layout_sent = layout
        bp = build_blueprint(
            has_world=layout[0], slugs=layout[1], frames=layout[2], has_eval=layout[3]
        )
        self.recording.send_blueprint(bp, make_active=True, make_default=True)

    def flush(self) -> None:
        """Wait until everything logged so far reached the recording's sinks."""
        self.recording.flush()

    def close(self) -> None:
        """Flush. A recording passed in by the caller stays open and keeps its sinks."""
        self.flush()

    def __enter__(self) -> RerunLogger:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
