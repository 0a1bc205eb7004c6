"""The default Rerun blueprint: the layout the viewer opens with."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Layout:
    """What the recording holds, as far as the blueprint cares.

    Attributes
    ----------
    has_world
        The map has 3D positions (``world/...`` entities exist).
    has_ceiling
        ``world/ceiling`` exists (hidden by default so the rooms show from above).
    eye
        ``(position, look_target, eye_up)`` of the 3D views, or None for Rerun's default.
    wide
        The map's footprint is long and narrow (a row of rooms): the map view gets the
        whole width, the scores and the document share the row below.
    configs
        ``(config slug, config name)`` for each config logged, in order.
    frames
        Entity-safe frame names logged under ``images/<frame>``.
    metrics
        Metric slugs logged under ``eval/<metric>/<config>``.
    eval_steps
        Steps of the ``query`` timeline that hold metrics (the last one plus one).
    has_summary
        A ``summary`` document exists.
    focus
        Slug of the config whose tab is open first (default: the first).
    query_list
        The ``query_list`` text log exists (one row per query step).
    """

    has_world: bool = False
    has_ceiling: bool = False
    eye: tuple | None = None
    wide: bool = False
    configs: tuple = ()
    frames: tuple = ()
    metrics: tuple = ()
    eval_steps: int = 0
    has_summary: bool = False
    focus: str | None = None
    query_list: bool = False


#: Entity of the text log that names each step of the ``query`` timeline.
QUERY_LIST = "query_list"
#: Entities (one per config) of a query's evaluation scores in words.
QUERY_SCORES = "query_scores"


def _query_list_view(rrb: Any) -> Any:
    """The queries by step (the step, then the text; no entity or level columns);
    clicking one moves the ``query`` timeline to it."""
    from rerun.blueprint.encodings import TextLogColumn, TimelineColumn

    columns = rrb.archetypes.TextLogColumns(
        timeline_columns=[TimelineColumn("query")],
        text_log_columns=[
            TextLogColumn("EntityPath", visible=False),
            TextLogColumn("LogLevel", visible=False),
            TextLogColumn("Body"),
        ],
    )
    return rrb.TextLogView(name="queries", origin=QUERY_LIST, columns=columns)


def _with_query_list(rrb: Any, layout: Layout, view: Any) -> Any:
    """``view`` beside the list of queries by step, when the recording has one."""
    if not layout.query_list:
        return view
    return rrb.Horizontal(view, _query_list_view(rrb), column_shares=[3, 1])


def _config_panel(rrb: Any, layout: Layout, c: str | None, name: str) -> Any:
    """One config: its 3D views (matches; scores), its images, its query-set document.

    View titles carry the config's name; the document's title carries the query.
    """
    eye = None
    if layout.eye is not None:
        position, target, up = layout.eye
        eye = rrb.EyeControls3D(kind="Orbital", position=position, look_target=target, eye_up=up)
    hidden = rrb.EntityBehavior(visible=False)
    if c is None:  # only the map so far: its 3D view, or a pixel map's images
        only: list[Any] = []
        if layout.has_world:
            only.append(
                rrb.Spatial3DView(
                    name="map",
                    origin="world",
                    contents=["+ world/map", "+ world/ceiling"],
                    overrides={"world/ceiling": hidden} if layout.has_ceiling else None,
                    eye_controls=eye,
                )
            )
        if layout.frames:
            images = [
                rrb.Spatial2DView(
                    name=str(frame), origin=f"images/{frame}", contents="+ $origin/rgb"
                )
                for frame in layout.frames
            ]
            only.append(rrb.Tabs(*images, name="images"))
        return only[0] if len(only) == 1 else rrb.Vertical(*only, name=name)
    doc: Any = rrb.TextDocumentView(name=f"{name}: query set", origin=f"queries/{c}")
    if layout.metrics:  # an evaluation: the query's scores above its query set
        scores_doc = rrb.TextDocumentView(
            name=f"{name}: this query's scores", origin=f"{QUERY_SCORES}/{c}"
        )
        doc = rrb.Vertical(scores_doc, doc, row_shares=[1, 4])
    doc = _with_query_list(rrb, layout, doc)
    views: list[Any] = []
    if layout.has_world:
        matches = rrb.Spatial3DView(
            name=f"{name}: map and matches",
            origin="world",
            contents=[
                "+ world/map",
                "+ world/ceiling",
                f"+ world/matches/{c}",
                f"+ world/rejected/{c}",
                f"+ world/instances/{c}/**",
            ],
            overrides={"world/ceiling": hidden} if layout.has_ceiling else None,
            eye_controls=eye,
        )
        scores = rrb.Spatial3DView(
            name=f"{name}: scores (0.5 = threshold)",
            origin="world",
            contents=[f"+ world/scores/{c}/**", f"+ world/instances/{c}/**"],
            overrides={f"world/scores/{c}/ceiling": hidden} if layout.has_ceiling else None,
            eye_controls=eye,
        )
        if layout.wide:
            below = rrb.Horizontal(scores, doc, column_shares=[1, 1])
            views.append(rrb.Vertical(matches, below, row_shares=[3, 2], name=name))
        else:
            views.append(
                rrb.Horizontal(matches, rrb.Vertical(scores, doc), column_shares=[3, 2], name=name)
            )
    if layout.frames:
        tabs = [
            rrb.Horizontal(
                rrb.Spatial2DView(
                    name=f"{name}: {frame} image and mask",
                    origin=f"images/{frame}",
                    contents=["+ $origin/rgb", f"+ $origin/{c}/mask", f"+ $origin/{c}/instances"],
                ),
                rrb.Spatial2DView(
                    name=f"{name}: {frame} scores",
                    origin=f"images/{frame}",
                    contents=[f"+ $origin/{c}/scores", f"+ $origin/{c}/instances"],
                ),
                name=str(frame),
            )
            for frame in layout.frames
        ]
        images = rrb.Tabs(*tabs, name="images")
        if layout.has_world:
            views.append(images)
        else:
            views.append(rrb.Horizontal(images, doc, column_shares=[3, 2]))
    if not views:
        return rrb.Vertical(doc, name=name)
    return rrb.Vertical(*views, name=name) if len(views) > 1 else views[0]


#: The title of each metric's plot (a metric not named here: ``<metric> per query``).
METRIC_TITLES = {
    "f1": "F1 per query",
    "precision": "precision per query",
    "recall": "recall per query",
    "iou": "IoU per query",
    "ap": "AP per query",
    "absence": "absence queries: 1 = answered with nothing (right), 0 = matched something",
}


def _eval_panel(rrb: Any, layout: Layout) -> Any:
    """One plot per metric (x: the query timeline, one series per config) and the summary.

    The x axis runs on past the last step, so the legend in the right corner sits over
    empty plot, never over the data.
    """
    last = max(layout.eval_steps - 1, 0)
    x_range = rrb.TimeRange(
        start=rrb.TimeRangeBoundary.absolute(seq=0),
        end=rrb.TimeRangeBoundary.absolute(seq=last + max(2, (last + 1) * 3 // 4)),
    )
    plots = [
        rrb.TimeSeriesView(
            name=METRIC_TITLES.get(m, f"{m} per query"),
            origin=f"eval/{m}",
            plot_legend=rrb.PlotLegend(corner="RightTop", visible=True),
            axis_x=rrb.TimeAxis(view_range=x_range, zoom_lock=False),
            axis_y=rrb.ScalarAxis(range=(0.0, 1.05)),
        )
        for m in layout.metrics
    ]
    parts: list[Any] = []
    if plots:
        parts.append(rrb.Grid(*plots, grid_columns=2 if len(plots) > 1 else 1))
    if layout.has_summary:
        parts.append(
            _with_query_list(rrb, layout, rrb.TextDocumentView(name="Comparison", origin="summary"))
        )
    elif plots and layout.query_list:
        parts.append(_query_list_view(rrb))
    if len(parts) == 2:
        return rrb.Horizontal(*parts, column_shares=[3, 2], name="evaluation")
    return rrb.Vertical(*parts, name="evaluation")


def build_blueprint(layout: Layout) -> Any:
    """A :class:`rerun.blueprint.Blueprint` for what the recording holds.

    One tab per config (the tab bar is the config selector; each tab's views are named
    after the config): a 3D view of the map and the config's matches, seen from above
    with the ceiling hidden; a 3D view of its score colours; the query-set document of
    the current query (its title names the query, then the positives and negatives).
    Pixel maps get one tab of 2D views per frame. Evaluation metrics, when logged, get
    their own tab. The time panel is on the ``query`` timeline: scrubbing it steps
    through the queries, and every config's tab shows the same query; the queries list
    (the ``query_list`` text log) names each step, and clicking one goes to it.
    """
    import rerun.blueprint as rrb

    panels = [_config_panel(rrb, layout, c, name) for c, name in layout.configs]
    names = [c for c, _ in layout.configs]
    if layout.metrics or layout.has_summary:
        panels.append(_eval_panel(rrb, layout))
    if not panels and (layout.has_world or layout.frames):
        panels.append(_config_panel(rrb, layout, None, "map"))
    if not panels:
        panels.append(rrb.TextDocumentView(name="Query set", origin="queries"))
    if len(panels) == 1:
        root = panels[0]
    else:
        active = names.index(layout.focus) if layout.focus in names else 0
        root = rrb.Tabs(*panels, active_tab=active)
    return rrb.Blueprint(
        root,
        rrb.TimePanel(timeline="query", state="collapsed", play_state="Paused"),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        collapse_panels=False,
    )
