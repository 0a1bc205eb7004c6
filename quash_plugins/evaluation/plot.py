"""Plots of evaluation results (matplotlib, imported on use)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..core.atomic import atomic_write
from ..core.errors import QuashError
from ..core.palette import series_style as palette_style

#: The ``Software`` text of every PNG written here: how a previous plot is recognised.
PNG_SOFTWARE = "quash-plugins"


def is_plot_png(path: str | Path) -> bool:
    """True when ``path`` is a PNG written by :func:`plot_precision_recall`.

    Such a plot may be replaced without ``--force``; any other file may not.
    """
    import struct

    try:
        with open(path, "rb") as f:
            if f.read(8) != b"\x89PNG\r\n\x1a\n":
                return False
            for _ in range(64):  # text chunks come before the image data
                head = f.read(8)
                if len(head) < 8:
                    return False
                length, kind = struct.unpack(">I4s", head)
                if kind in (b"IDAT", b"IEND") or length > 2**20:
                    return False
                data = f.read(length)
                f.read(4)  # CRC
                if kind == b"tEXt" and data == b"Software\0" + PNG_SOFTWARE.encode():
                    return True
    except OSError:
        return False
    return False


#: matplotlib's spelling of the palette's markers (core.palette.SERIES_MARKERS).
_MPL_MARKERS = {
    "circle": "o",
    "diamond": "D",
    "square": "s",
    "cross": "X",
    "up": "^",
    "down": "v",
    "asterisk": "*",
}


def series_style(k: int) -> tuple[tuple[float, float, float], str]:
    """The colour (RGB in 0-1) and matplotlib marker of the ``k``-th method: the Rerun
    viewer's (:func:`quash_plugins.core.palette.series_style`), so a method has the same
    colour in ``demo.png`` as in ``demo.rrd``."""
    (r, g, b), marker = palette_style(k)
    return (r / 255, g / 255, b / 255), _MPL_MARKERS[marker]


#: The iso-F1 curves drawn behind the points, each labelled with its F1 right of the axes.
ISO_F1 = (0.2, 0.4, 0.6, 0.8)
#: Room (points) right of the axes for those labels; the legend stands beyond it.
ISO_LABEL_PT = 34
#: Width of the axes (inches) whatever the legend's.
AXES_WIDTH_IN = 5.5


def _legend_label(c: dict[str, Any]) -> str:
    """A method's legend entry: its name, mean F1, absence score, the present queries it
    answered with nothing (their dots are all at the origin), and what it was given."""
    text = f"{c['name']}: F1 {c['mean']['f1']:.2f}"
    absence = c.get("absence") or {}
    if isinstance(absence.get("score"), (int, float)):
        text += f", absence {absence['score']:.2f}"
    empty, n = absence.get("present_empty"), len(c.get("per_query") or {})
    if isinstance(empty, int) and empty and n:  # those queries' dots all sit at (0, 0)
        text += f", present -> empty {empty}/{n}"
    if c.get("given"):
        text += f"\ngiven {c['given']}"
    return text


#: Where a zoom of the means may go (axes fraction: x0, y0, width, height), the corner
#: holding the fewest points is taken.
#: The left and bottom corners leave room for the inset's own tick labels, which would
#: otherwise be drawn over the main axes' labels.
ZOOM_CORNERS = (
    (0.13, 0.55, 0.36, 0.4),
    (0.13, 0.14, 0.36, 0.36),
    (0.58, 0.55, 0.38, 0.4),
    (0.58, 0.14, 0.38, 0.36),
)
#: Means closer than this (in recall and precision) overlap at the plot's scale.
ZOOM_BELOW = 0.03
#: Means closer than this are the same point (equal to the three decimals the tables
#: print): no zoom shows them apart, so the legend says which mean each one shares.
SAME_POINT = 0.0005


def _same_point_as(xy: Any) -> list[int | None]:
    """For each mean, the index of the first earlier mean at the same point (within
    :data:`SAME_POINT` in recall and precision), or None."""
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    first: list[int | None] = []
    for i in range(len(xy)):
        roots = (j for j in range(i) if first[j] is None)
        first.append(next((j for j in roots if np.abs(xy[i] - xy[j]).max() < SAME_POINT), None))
    return first


def _overlapping_means(xy: Any) -> list[int]:
    """The largest group of means that overlap one another (linked by gaps under
    :data:`ZOOM_BELOW` in recall and precision; on a tie, the one with the closest
    pair), as indices; [] when no two overlap."""
    n = len(xy)
    gaps = np.abs(xy[:, None, :] - xy[None, :, :]).max(axis=2)
    np.fill_diagonal(gaps, np.inf)
    group = list(range(n))
    for i in range(n):
        for j in range(i + 1, n):
            if gaps[i, j] < ZOOM_BELOW and group[i] != group[j]:
                old, new = group[j], group[i]
                group = [new if g == old else g for g in group]
    members: dict[int, list[int]] = {}
    for i, g in enumerate(group):
        members.setdefault(g, []).append(i)
    linked = [m for m in members.values() if len(m) > 1]
    if not linked:
        return []
    return max(linked, key=lambda m: (len(m), -gaps[np.ix_(m, m)].min()))


def _zoom_on_the_means(ax: Any, means: list[tuple[float, float, Any, str]], points: Any) -> Any:
    """An inset that shows overlapping means apart (a table whose rows score alike: the
    antonyms all at recall ~1, precision ~0.05), in the corner of the axes that covers the
    fewest points, with the zoomed area marked; None when no two means overlap. Only the
    largest group of overlapping means is zoomed on."""
    xy = np.array([(m[0], m[1]) for m in means], dtype=float).reshape(-1, 2)
    # means at the same point stand for one: a zoom cannot show them apart (the legend
    # names them), and a group of such means alone gets no zoom at all
    distinct = [i for i, same in enumerate(_same_point_as(xy)) if same is None]
    picked = [distinct[i] for i in _overlapping_means(xy[distinct])]
    if not picked:
        return None
    lo, hi = xy[picked].min(axis=0), xy[picked].max(axis=0)
    pad = max(0.15 * float((hi - lo).max()), 0.01)
    lo, hi = lo - pad, hi + pad
    x0, x1 = ax.get_xlim()
    y0, y1 = ax.get_ylim()
    lo, hi = np.maximum(lo, [x0, y0]), np.minimum(hi, [x1, y1])  # the mark stays inside
    frac = (points - [x0, y0]) / [x1 - x0, y1 - y0]  # the points in axes fraction
    zoomed = (np.array([lo, hi]) - [x0, y0]) / [x1 - x0, y1 - y0]

    def crowd(corner: tuple) -> tuple[int, int]:
        cx, cy, w, h = corner
        inside = (
            (frac[:, 0] >= cx)
            & (frac[:, 0] <= cx + w)
            & (frac[:, 1] >= cy)
            & (frac[:, 1] <= cy + h)
        )
        over = not (
            zoomed[1, 0] < cx or zoomed[0, 0] > cx + w or zoomed[1, 1] < cy or zoomed[0, 1] > cy + h
        )
        return (int(over), int(inside.sum()))  # never over the zoomed area itself

    corner = min(ZOOM_CORNERS, key=crowd)
    inset = ax.inset_axes(list(corner))
    for r, p, color, marker in means:
        inset.scatter([r], [p], s=60, color=color, marker=marker, edgecolor="black", zorder=3)
    inset.set(xlim=(lo[0], hi[0]), ylim=(lo[1], hi[1]))
    inset.set_title("the means, zoomed", fontsize=7)
    inset.tick_params(labelsize=6)
    ax.indicate_inset_zoom(inset, edgecolor="dimgrey")
    return inset


def precision_recall_figure(
    configs: Sequence[dict[str, Any]],
    title: str = "precision vs recall",
    *,
    dots: str = "one query",
    mean: str = "mean over the present queries",
) -> Any:
    """The figure :func:`plot_precision_recall` writes (a ``matplotlib.figure.Figure``).

    One colour per method: a large marker at its macro mean over the present queries and
    a small dot per query. The legend, right of the axes so it covers no point, names each
    method with its mean F1, its absence score (the share of absence queries it answered
    with nothing), how many present queries it answered with nothing and what it was given, then what the markers and the dotted iso-F1
    curves (each labelled with its F1) mean: ``mean`` and ``dots`` say what the markers are
    (a plot whose dots are seeds, not queries: ``dots="one seed"``). When means overlap,
    an inset in the emptiest corner shows them apart; a mean at the same point as
    another one (two rules that answer alike) has a legend line naming that one.
    """
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        from matplotlib.lines import Line2D
        from matplotlib.transforms import ScaledTranslation
    except ImportError:
        raise QuashError('Plots need matplotlib: pip install "quash-plugins[plots]"') from None
    placed = [c for c in configs if c["mean"]["f1"] is not None]
    same = _same_point_as([(c["mean"]["recall"], c["mean"]["precision"]) for c in placed])
    # a mean drawn over another one's: the legend says so, as no zoom can show them apart
    shares = {
        c["name"]: placed[j]["name"] for c, j in zip(placed, same, strict=True) if j is not None
    }
    n_lines = sum(1 + bool(c.get("given")) for c in configs) + 3 + len(shares)
    fig, ax = plt.subplots(figsize=(AXES_WIDTH_IN + 0.9, max(5.2, 1.0 + 0.16 * n_lines)), dpi=110)
    handles: list[Any] = []
    means: list[tuple[float, float, Any, str]] = []
    for i, c in enumerate(configs):
        color, marker = series_style(i)
        pq = list((c.get("per_query") or {}).values())
        if pq:
            ax.scatter(
                [q["recall"] for q in pq],
                [q["precision"] for q in pq],
                s=9,
                alpha=0.35,
                color=color,
                marker=marker,
            )
        if c["mean"]["f1"] is None:  # nothing scored (absence queries only): no mean to place
            continue
        means.append((c["mean"]["recall"], c["mean"]["precision"], color, marker))
        handles.append(
            ax.scatter(
                [c["mean"]["recall"]],
                [c["mean"]["precision"]],
                s=90,
                color=color,
                marker=marker,
                edgecolor="black",
                label=_legend_label(c)
                + (
                    f"\nits mean at the same point as {shares[c['name']]}'s"
                    if c["name"] in shares
                    else ""
                ),
                zorder=3,
            )
        )
    r = np.linspace(0.01, 1, 200)
    for f in ISO_F1:
        p = f * r / (2 * r - f)
        ok = (p > 0) & (p <= 1)
        ax.plot(r[ok], p[ok], color="grey", lw=0.6, ls=":")
        # right of the axes, where the curve ends (recall 1): over no point
        ax.annotate(
            f"F1 {f:.1f}",
            (1.0, f / (2 - f)),
            xycoords=("axes fraction", "data"),
            xytext=(3, 0),
            textcoords="offset points",
            ha="left",
            va="center",
            fontsize=7,
            color="dimgrey",
            annotation_clip=False,
        )
    ax.set(
        xlim=(-0.02, 1.02),
        ylim=(-0.02, 1.02),
        xlabel="recall (share of the label's items matched)",
        ylabel="precision (share of the matched items that carry the label)",
        title=title,
    )
    ax.xaxis.label.set_fontsize(9)
    ax.yaxis.label.set_fontsize(9)
    offsets = [col.get_offsets() for col in ax.collections]
    points = np.vstack(offsets) if offsets else np.zeros((0, 2))
    _zoom_on_the_means(ax, means, np.asarray(points, dtype=float))
    if handles:
        keys = [
            Line2D([], [], ls="", marker="o", ms=9, mfc="white", mec="black"),
            Line2D([], [], ls="", marker="o", ms=3, mfc="grey", mec="grey", alpha=0.5),
            Line2D([], [], color="grey", lw=0.6, ls=":"),
        ]
        names = [mean, dots, "iso-F1 curves"]
        legend = ax.legend(
            [*handles, *keys],
            [h.get_label() for h in handles] + names,
            fontsize=7,
            loc="upper left",
            bbox_to_anchor=(1.0, 1.0),
            bbox_transform=ax.transAxes
            + ScaledTranslation(ISO_LABEL_PT / 72, 0, fig.dpi_scale_trans),
            borderaxespad=0.0,
        )
        # the axes keep their size; the figure widens by the legend's width
        fig.canvas.draw()
        extra = legend.get_window_extent().width / fig.dpi + ISO_LABEL_PT / 72
        fig.set_size_inches(AXES_WIDTH_IN + 0.9 + extra, fig.get_size_inches()[1])
    fig.tight_layout()
    return fig


def plot_precision_recall(
    configs: Sequence[dict[str, Any]],
    path: str | Path,
    title: str = "precision vs recall",
    **legend: str,
) -> Path:
    """Precision against recall per method (mean: large marker; per query: small dots),
    written as a PNG: :func:`precision_recall_figure` (``legend``: its ``dots`` and
    ``mean``)."""
    fig = precision_recall_figure(configs, title, **legend)
    import matplotlib.pyplot as plt  # there: the figure was made with it

    path = Path(path)
    with atomic_write(path, suffix=".png") as tmp:
        fig.savefig(tmp, format="png", metadata={"Software": PNG_SOFTWARE}, bbox_inches="tight")
    plt.close(fig)
    return path
