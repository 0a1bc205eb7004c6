"""The Rerun logger: its recording, its state, the blueprint and its lifecycle.

:class:`RerunLogger` logs maps, query results and evaluation metrics to a Rerun
recording. What it logs is in one module per step of the data flow, each a base of the
class: the map (``_log_map.MapLogging``), a query's result (``_log_result.ResultLogging``)
and an evaluation (``_log_eval.EvalLogging``). This module holds what they share: the
recording, the state set up in ``__init__``, the blueprint sent for what was logged,
flushing and closing.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from ..core.errors import QuashError
from ..core.text import label_key
from ._display import UP_AXES, slugify
from ._log_eval import EvalLogging
from ._log_map import MapLogging
from ._log_result import ResultLogging, _ConfigState

log = logging.getLogger(__name__)


def import_rerun() -> Any:
    """Import ``rerun`` or raise a :class:`QuashError` naming the extra to install."""
    try:
        import rerun as rr
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise QuashError(
            'Rerun output needs the rerun SDK: pip install "quash-plugins[rerun]"'
        ) from exc
    return rr


class RerunLogger(MapLogging, ResultLogging, EvalLogging):
    """Log maps and query results to an explicit Rerun recording.

    The logger writes only to ``recording`` (or to a new one it creates); it never uses
    or changes Rerun's global or thread-local recording.

    The map is logged once, as static data; each query adds only what is its own: the
    positions of its matches, one small class id per drawn item for the score colours,
    its instance boxes and its document. Results are grouped by config (one tab each in
    the blueprint) and placed on the ``query`` timeline by query index.

    One logger holds one map and one query per step: a second, different map, or another
    query at a step in use, raises :class:`QuashError` rather than corrupting what was
    logged (use a new recording and logger per map; continue the step numbering).

    Parameters
    ----------
    recording
        A :class:`rerun.RecordingStream` with its sinks already attached (``save``,
        ``connect_grpc``, ``serve_grpc``...). None creates ``rr.RecordingStream(app_id)``
        with Rerun's buffered sink; attach a sink through :attr:`recording`.
    app_id
        Application id of a recording created here.
    max_display_points
        Most items drawn per 3D layer (map, matches, scores). Bigger maps are thinned for
        display only, with a deterministic even stride; queries always use every item.
        A pixel map's images are drawn whole (``max_frames`` of them).
    max_boxes
        Voxel maps with at most this many drawn voxels are drawn as boxes, bigger ones
        as points with the voxel radius.
    max_frames
        Most frames of a pixel map drawn under ``images/``.
    colormap
        Colormap name for scores (matplotlib's names; a built-in table otherwise).
    up
        The map's up axis: ``"auto"`` (the default: the one the map's adapter recorded in
        ``source["up"]``, ``"+y"`` for VLMaps camera-base maps and ``"+z"`` for
        mobile-base ones; ``"+z"`` when the format does not say), one of ``"+z"``,
        ``"-z"``, ``"+y"``, ``"-y"``, ``"+x"``, ``"-x"`` (for every map, over what it
        records), or None for no orientation. It orients the views (top-down by default)
        and finds the ceiling, which is logged apart and hidden so the rooms can be seen
        from above.
    score_classes
        Number of colour steps of the score layers (class ids of one annotation context).
        The threshold (display score 0.5) is always a class boundary: the classes
        labelled ``(match)`` hold only scores at or above it, for odd counts too.
    blueprint
        Send the layout described in ``docs/rerun.md`` (made the active one: the viewer
        then shows these views only, on the ``query`` timeline). False sends none, so a
        recording that holds a robot's own data keeps its layout (yours, or the viewer's
        own views of everything logged).

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
        up: str | None = "auto",
        score_classes: int = 32,
        blueprint: bool = True,
    ) -> None:
        rr = import_rerun()
        self.rr = rr
        if recording is None:
            recording = rr.RecordingStream(app_id)
        elif not isinstance(recording, rr.RecordingStream):
            raise QuashError(
                f"RerunLogger needs a rerun.RecordingStream; got {type(recording).__name__}."
            )
        if up is not None and up != "auto" and up not in UP_AXES:
            raise QuashError(
                f"RerunLogger: up must be 'auto', one of {', '.join(UP_AXES)} or None; got {up!r}."
            )
        if not 2 <= int(score_classes) <= 65535:
            raise QuashError("RerunLogger: score_classes must be in [2, 65535].")
        self.recording = recording
        self.max_display_points = int(max_display_points)
        self.max_boxes = int(max_boxes)
        self.max_frames = int(max_frames)
        self.colormap = colormap
        self.up = up
        self.score_classes = int(score_classes)
        self.blueprint = bool(blueprint)
        self._map_key: tuple | None = None  # the fingerprint of the map logged
        self._map_ref: Any = None  # a weak reference to it
        self._map_name = ""  # the map logged, in words
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
        self._eval_colors: dict[str, int] = {}  # config slug -> its series style's index
        self._eval_last = -1
        self._has_summary = False
        self._listed: dict[int, str] = {}  # step -> the query named there
        self._config_slugs: dict[str, str] = {}  # config name -> its entity name

    def _config_slug(self, name: str) -> str:
        """The entity-safe name of config ``name``, one per name: a second name that
        slugs alike (``my-method``, ``My Method``) gets ``_2``, then ``_3``..."""
        slug = self._config_slugs.get(name)
        if slug is None:
            base = slug = slugify(name, "config")
            taken = set(self._config_slugs.values())
            k = 2
            while slug in taken:
                slug, k = f"{base}_{k}", k + 1
            self._config_slugs[name] = slug
        return slug

    # ------------------------------------------------------------------ evaluations
    def log_report(self, lmap: Any, report: Any) -> None:
        """Log an evaluation whole: the map, every config's results coloured by outcome
        against their ground truth, the per-query metrics and the comparison; the viewer
        opens on the config with the best mean F1.

        ``report`` is an :class:`~quash_plugins.evaluation.report.EvalReport` of
        ``evaluate(lmap, ..., keep_results=True)`` on this map: result *i* of each config
        is logged at step *i* (:meth:`log_result`; the present queries, then the absence
        queries), with its ground truth: the items of its query's label (those of every
        label of that name), none for an absence query, so that every match there is a
        false positive; the items counted are those the evaluation scored (a label >= 0,
        not one of the labels the evaluation excluded, ``report.provenance["exclude"]``).
        Then :meth:`log_evaluation` and :meth:`focus`.

        A report without results (``keep_results=False``) raises :class:`QuashError`
        before anything is logged: log its metrics with :meth:`log_evaluation`.
        """
        results = dict(getattr(report, "results", None) or {})
        configs = list(report.configs)
        missing = [c["name"] for c in configs if c["name"] not in results]
        if missing:
            raise QuashError(
                f"log_report: the report holds no results of {', '.join(map(repr, missing))}: "
                "evaluate with keep_results=True, or log the metrics alone with "
                "log_evaluation(report.configs, report.queries, report.to_markdown(), "
                "absent=report.absent)."
            )
        if lmap.labels is None or not lmap.label_names:
            raise QuashError(
                "log_report: the map has no labels, so its results cannot be coloured by "
                "outcome: give the map the report was evaluated on."
            )
        labels = np.asarray(lmap.labels)
        names = list(lmap.label_names)
        excluded = {label_key(e) for e in (report.provenance or {}).get("exclude", ())}
        dropped = [i for i, n in enumerate(names) if label_key(n) in excluded]
        counted = (labels >= 0) & ~np.isin(labels, dropped)
        texts = [*report.queries, *report.absent]
        self.log_map(lmap)
        for c in configs:
            per_query = c.get("per_query") or {}
            absent = (c.get("absence") or {}).get("per_query") or {}
            for i, r in enumerate(results[c["name"]]):
                q = texts[i] if i < len(texts) else r.query
                label = (per_query.get(q) or absent.get(q) or {}).get("label")
                present = q in per_query
                ids = [k for k, n in enumerate(names) if n == label] if present else []
                truth = np.isin(labels, ids)
                self.log_result(lmap, r, index=i, truth=truth, counted=counted, label=label)
        self.log_evaluation(configs, report.queries, report.to_markdown(), absent=report.absent)
        if configs:
            self.focus(report.best("f1")["name"])

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
        if not self.blueprint:  # the caller's recording keeps its own layout
            return
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
            query_list=bool(self._listed),
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
