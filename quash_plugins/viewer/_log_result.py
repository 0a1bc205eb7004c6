"""Logging one query's result on the map: its matches, score colours, instances, document.

:class:`ResultLogging` is the part of :class:`~quash_plugins.viewer.RerunLogger` that logs
a :class:`~quash_plugins.core.types.QueryResult` over the map logged by
:meth:`~quash_plugins.viewer._log_map.MapLogging.log_map` (the logger's state is set up
in ``RerunLogger.__init__``, in ``_rerun.py``).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import numpy as np

from ..core.errors import QuashError
from ..core.types import Instance, LatentMap, QueryResult
from ._blueprint import QUERY_LIST
from ._display import (
    OUTCOME_COLORS,
    OUTCOME_FN,
    OUTCOME_FP,
    OUTCOME_TP,
    OUTCOME_UNSCORED,
    colormap,
    outcomes,
    score_classes,
    thin,
)
from ._document import outcome_legend, queryset_markdown
from ._log_map import MATCH_COLOR, REJECTED_COLOR

#: Colour of instance boxes.
INSTANCE_COLOR = (255, 200, 0)


def _same_query(a: str, b: str) -> bool:
    """The same query text, white space aside (queries are compared as they are run)."""
    return " ".join(str(a).split()) == " ".join(str(b).split())


class _ConfigState:
    """What was logged for one config."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.scores_logged = False


class ResultLogging:
    """:meth:`log_result` and the config tabs; a base of ``RerunLogger``."""

    def focus(self, config_name: str) -> None:
        """Open the viewer on this config's tab (default: the first config logged)."""
        self._focus = self._config_slug(str(config_name))
        self._layout_changed()

    def log_result(
        self,
        lmap: LatentMap,
        result: QueryResult,
        index: int,
        *,
        truth: np.ndarray | None = None,
        counted: np.ndarray | None = None,
        label: str | None = None,
    ) -> None:
        """Log one query's result at ``query = index`` on the ``query`` timeline.

        Per config (``result.config_name``): ``world/matches/<config>`` (the matched
        items), ``world/rejected/<config>`` (those the presence check dropped, grey), the class ids of ``world/scores/<config>``, ``world/instances/<config>``
        and the document ``queries/<config>``; for pixel maps
        ``images/<frame>/<config>/{mask,scores,instances}`` (the mask's class 2: the pixels
        the presence check dropped). Each replaces the config's
        previous query, so scrubbing the timeline shows one query at a time per config.

        A step is one query in every config: another result of the same query at ``index``
        (another config's, or this one's again) is fine; another query at a step in use
        raises :class:`QuashError` naming both and a free index, before anything of it is
        logged. The map must be the one this logger logged (:meth:`log_map`).

        ``truth``: the query's ground truth, ``(N,)`` bool (all False for an absence
        query), and ``counted`` the items an evaluation scores (None: all; unlabelled and
        excluded items are neither right nor wrong); ``label`` names the ground truth in
        the document. With ``truth``, ``world/matches/<config>`` is coloured by outcome
        (``_display.OUTCOME_COLORS``): true positives blue, false positives vermillion,
        and the false negatives (the label's items not matched) in yellow with them; a
        match on an item not counted stays magenta. The document says which colour is
        which, with the counts. Without it (``quash query``) the matches are magenta.
        :meth:`log_report` passes them for an evaluation's results.
        """
        self.log_map(lmap)  # nothing when this map is logged already; another is refused
        if len(result.mask) != lmap.n:
            raise QuashError(
                f"Result for {result.query!r} has {len(result.mask)} items but the map has {lmap.n}."
            )
        outcome = None
        if truth is not None:
            for what, arr in (("truth", truth), ("counted", counted)):
                if arr is not None and np.shape(arr) != (lmap.n,):
                    raise QuashError(
                        f"log_result: {what} for {result.query!r} has shape {np.shape(arr)}; "
                        f"the map has {lmap.n} items: give one bool per item."
                    )
            outcome = outcomes(result.mask, truth, counted)
        index = int(index)
        self._check_step(index, result.query, "log_result")
        name = str(result.config_name or "quash")
        c = self._config_slug(name)
        state = self._configs.setdefault(c, _ConfigState(name))
        with self._at_query_step(index):
            self._log_result_at_step(lmap, result, index, c, state, outcome, label)
        self._layout_changed()

    @contextlib.contextmanager
    def _at_query_step(self, step: int | None = None) -> Iterator[None]:
        """Log at ``step`` of the ``query`` timeline (None: the caller sets each step);
        afterwards, whatever happens, the recording is at no query step, since it may be
        the caller's: what a robot stack logs next is not stamped with a query."""
        if step is not None:
            self.recording.set_time("query", sequence=step)
        try:
            yield
        finally:
            self.recording.disable_timeline("query")

    def _log_result_at_step(
        self,
        lmap: LatentMap,
        result: QueryResult,
        index: int,
        c: str,
        state: _ConfigState,
        outcome: np.ndarray | None = None,
        label: str | None = None,
    ) -> None:
        """:meth:`log_result` once the ``query`` time is set."""
        rr, rec = self.rr, self.recording
        self._list_query(index, result.query)
        notes = list(self._notes)
        if self._has_world:
            self._log_world(lmap, result, c, state, notes, outcome)
        for fname, frame in self._frames:
            sl = slice(frame.offset, frame.offset + frame.size)
            hw = (frame.height, frame.width)
            # class 1: the match; class 2: what the presence check dropped (grey)
            seg = np.asarray(result.mask[sl]).astype(np.uint8)
            if result.rejected is not None:
                seg[np.asarray(result.rejected[sl]) & (seg == 0)] = 2
            seg = seg.reshape(hw)
            base = f"images/{fname}/{c}"
            rec.log(f"{base}/mask", rr.SegmentationImage(seg, opacity=0.5))
            heat = colormap(np.asarray(result.display_scores[sl]), self.colormap)
            rec.log(f"{base}/scores", rr.Image(heat.reshape(*hw, 3)))
            self._log_pixel_instances(lmap, result, base, frame.frame_id)
        legend = []
        if outcome is not None and self._has_world:
            legend = outcome_legend(np.bincount(outcome, minlength=5), label)
        text = queryset_markdown(lmap, result, index, notes, legend)
        rec.log(f"queries/{c}", rr.TextDocument(text, media_type=rr.MediaType.MARKDOWN))

    def _check_step(self, step: int, query: str, caller: str) -> None:
        """Refuse a second query at ``step``: a step of the ``query`` timeline is one
        query, shown in every config's tab and named once in the query list."""
        named = self._listed.get(step)
        if named is None or _same_query(named, query):
            return
        free = max(self._listed) + 1
        if caller == "log_result":
            fix = (
                f"Log {str(query)!r} at a step of its own, e.g. index={free} (the step after "
                "the last one used); for a second batch of results, continue the numbering "
                f"(enumerate(results, start={free}))."
            )
        elif caller == "log_evaluation":
            fix = (
                "log_evaluation puts query i of its list at step i (absence query j at "
                "len(queries) + j): log the results at those steps, or the evaluation with "
                "a RerunLogger of its own."
            )
        else:
            fix = f"Give {str(query)!r} a step of its own, e.g. {free}."
        raise QuashError(
            f"{caller}: step {step} of the query timeline already holds the query "
            f"{named!r}, so {str(query)!r} cannot be logged there: a step is one query, "
            "named once in the query list and shown at that step in every config's tab. " + fix
        )

    def _list_query(self, step: int, query: str, caller: str = "log_result") -> None:
        """Name the query at ``step`` once, in the ``query_list`` text log (at that step):
        the list of queries by step, where clicking a row moves the timeline to it.
        Another query at a named step is refused (:meth:`_check_step`)."""
        if step in self._listed:
            self._check_step(step, query, caller)
            return
        self._listed[step] = str(query)
        self.recording.log(QUERY_LIST, self.rr.TextLog(str(query)))
        self._layout_changed()

    def _log_world(
        self,
        lmap: LatentMap,
        result: QueryResult,
        c: str,
        state: _ConfigState,
        notes: list[str],
        outcome: np.ndarray | None = None,
    ) -> None:
        rr, rec = self.rr, self.recording
        if outcome is None:
            matched = np.flatnonzero(result.mask)
            shown = thin(matched, self.max_display_points)
            colors: object = MATCH_COLOR
            what = "matched items"
        else:  # by outcome: the matches, and the label's items missed (false negatives)
            matched = np.flatnonzero(outcome)
            shown = thin(matched, self.max_display_points)
            table = np.zeros((OUTCOME_UNSCORED + 1, 3), np.uint8)
            for k in (OUTCOME_TP, OUTCOME_FP, OUTCOME_FN):
                table[k] = OUTCOME_COLORS[k]
            table[OUTCOME_UNSCORED] = MATCH_COLOR
            colors = table[outcome[shown]]
            what = "matched and missed items"
        if len(shown) < len(matched):
            notes.append(
                f"The mask layer shows {len(shown):,} of {len(matched):,} {what} (display only)."
            )
        rec.log(
            f"world/matches/{c}",
            self._primitive(lmap.positions[shown], 0.55, 0.6, colors=colors),
        )
        # what the presence check dropped: an absent object's look-alikes, in grey
        dropped = np.flatnonzero(result.rejected) if result.rejected is not None else []
        if len(dropped):
            dropped = thin(dropped, self.max_display_points)
            rec.log(
                f"world/rejected/{c}",
                self._primitive(lmap.positions[dropped], 0.5, 0.55, colors=REJECTED_COLOR),
            )
        else:
            rec.log(f"world/rejected/{c}", rr.Clear(recursive=True))
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
                labels=[_instance_label(result.query, i) for i in insts],
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
                labels=[_instance_label(result.query, i) for i in insts],
            ),
        )


def _instance_label(query: str, inst: Instance) -> str:
    """A box's label, the same in 3D and on an image: ``<query> #<id> (<size>, <mean score>)``."""
    return f"{query} #{inst.id} ({inst.size}, {inst.mean_score:.2f})"
