"""The default Rerun blueprint: the layout the viewer opens with."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any


def build_blueprint(
    *,
    has_world: bool,
    slugs: Sequence[str] = (),
    frames: Sequence[str] = (),
    has_eval: bool = False,
) -> Any:
    """A :class:`rerun.blueprint.Blueprint` for what the recording holds.

    Layout: on the left a 3D view of ``world`` (map, matches, instances) and a second
    3D view of the score colormap (Rerun's view queries only accept a trailing ``/**``
    wildcard, so the query slugs are listed explicitly); for pixel maps, one tab of 2D views per logged frame
    (RGB with the mask over it, and the score heatmap); on the right the query-set
    document of the current query and, for ``quash eval``, a time series of the metrics.
    The time panel is set to the ``query`` timeline so a person scrubs through queries.

    Parameters
    ----------
    has_world
        The map has 3D positions (``world/...`` entities exist).
    slugs
        Entity names of the queries logged so far (``world/queries/<slug>``).
    frames
        Entity-safe frame names logged under ``images/<frame>``.
    has_eval
        Evaluation scalars exist under ``eval/``.
    """
    import rerun.blueprint as rrb

    left: list[Any] = []
    if has_world:
        views = [
            rrb.Spatial3DView(
                name="Map and matches",
                origin="world",
                contents=["+ world/**", *[f"- world/queries/{q}/scores/**" for q in slugs]],
            )
        ]
        if slugs:
            views.append(
                rrb.Spatial3DView(
                    name="Scores",
                    origin="world",
                    contents=[
                        *[f"+ world/queries/{q}/scores/**" for q in slugs],
                        *[f"+ world/queries/{q}/instances/**" for q in slugs],
                    ],
                )
            )
        left.append(rrb.Horizontal(*views))
    if frames:
        tabs = []
        for frame in frames:
            tabs.append(
                rrb.Horizontal(
                    rrb.Spatial2DView(
                        name=f"{frame}: image and mask",
                        origin=f"images/{frame}",
                        contents=["+ $origin/rgb", "+ $origin/mask", "+ $origin/instances"],
                    ),
                    rrb.Spatial2DView(
                        name=f"{frame}: scores",
                        origin=f"images/{frame}",
                        contents=["+ $origin/scores", "+ $origin/instances"],
                    ),
                    name=str(frame),
                )
            )
        left.append(rrb.Tabs(*tabs, name="Images"))
    right: list[Any] = [rrb.TextDocumentView(name="Query set", origin="queries")]
    if has_eval:
        right.append(rrb.TimeSeriesView(name="Evaluation", origin="eval"))
    if not left:
        left.append(rrb.TextDocumentView(name="Summary", origin="queries"))
        right = right[1:] or [rrb.TextDocumentView(name="Query set", origin="queries")]
    main = rrb.Horizontal(
        rrb.Vertical(*left),
        rrb.Vertical(*right),
        column_shares=[3, 1],
    )
    return rrb.Blueprint(
        main,
        rrb.TimePanel(timeline="query", expanded=True),
        rrb.SelectionPanel(expanded=False),
        collapse_panels=False,
    )
