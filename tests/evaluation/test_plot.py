"""The precision-recall plot: what its legend, axes and curves say, and that the legend
covers no data (read back from the figure object)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("matplotlib")

from quash_plugins.evaluation.plot import (  # noqa: E402
    ISO_F1,
    is_plot_png,
    plot_precision_recall,
    precision_recall_figure,
)


def _config(name, given, points, absence_score, present_empty):
    per_query = {
        f"q{i}": {"precision": p, "recall": r, "f1": 0.0 if p + r == 0 else 2 * p * r / (p + r)}
        for i, (r, p) in enumerate(points)
    }
    mean = {k: float(np.mean([q[k] for q in per_query.values()])) for k in ("precision", "recall")}
    mean["f1"] = float(np.mean([q["f1"] for q in per_query.values()]))
    return {
        "name": name,
        "given": given,
        "mean": mean,
        "per_query": per_query,
        "absence": {"score": absence_score, "present_empty": present_empty, "per_query": {}},
    }


#: Points in every corner, as a real run has them (a peer's low-precision dots bottom left
#: and bottom right, a method's good queries top right, empty answers at the origin).
CONFIGS = [
    _config("peer", "the query alone", [(0.05, 0.03), (0.9, 0.05), (0.02, 0.1)], 0.0, 0),
    _config(
        "quash-labels",
        "the label list (the map's label names)",
        [(0.95, 0.97), (0.0, 0.0), (0.0, 0.0), (0.9, 0.92)],
        1.0,
        2,
    ),
]


def _figure():
    fig = precision_recall_figure(CONFIGS, title="t")
    fig.canvas.draw()
    return fig, fig.axes[0]


def test_the_legend_covers_no_point():
    """The legend sat in the lower left corner of the axes, over the dots of the queries
    a peer answered with low precision and recall."""
    import matplotlib.pyplot as plt

    fig, ax = _figure()
    box = ax.get_legend().get_window_extent()
    points = np.vstack([c.get_offsets() for c in ax.collections])
    assert len(points) == sum(len(c["per_query"]) + 1 for c in CONFIGS)
    shown = ax.transData.transform(points)
    inside = (
        (shown[:, 0] >= box.x0)
        & (shown[:, 0] <= box.x1)
        & (shown[:, 1] >= box.y0)
        & (shown[:, 1] <= box.y1)
    )
    assert not inside.any(), points[inside]
    plt.close(fig)


def test_the_legend_says_method_score_absence_empty_answers_and_given():
    import matplotlib.pyplot as plt

    fig, ax = _figure()
    texts = [t.get_text() for t in ax.get_legend().get_texts()]
    for c in CONFIGS:
        [entry] = [t for t in texts if t.startswith(f"{c['name']}: ")]
        assert f"F1 {c['mean']['f1']:.2f}" in entry
        assert f"absence {c['absence']['score']:.2f}" in entry
        assert f"given {c['given']}" in entry
        n = len(c["per_query"])
        empty = c["absence"]["present_empty"]
        assert (f"present -> empty {empty}/{n}" in entry) == bool(empty)
    # what the markers and the dotted curves are
    assert texts[-3:] == ["mean over the present queries", "one query", "iso-F1 curves"]
    plt.close(fig)


def test_the_iso_f1_curves_are_labelled_and_the_origin_dots_are_whole():
    import matplotlib.pyplot as plt

    fig, ax = _figure()
    labels = {t.get_text(): t for t in ax.texts}
    axes, legend = ax.get_window_extent(), ax.get_legend().get_window_extent()
    for f in ISO_F1:
        label = labels[f"F1 {f:.1f}"]
        x, y = label.xy
        # at the height where its curve ends (recall 1): precision = f / (2 - f)
        assert x == 1.0 and y == pytest.approx(f / (2 - f))
        # right of the axes (over no point), left of the legend
        box = label.get_window_extent()
        assert axes.x1 < box.x0 and box.x1 < legend.x0
    # a query answered with nothing sits at (0, 0): the axes start below it, not on it
    assert ax.get_xlim()[0] < 0 and ax.get_ylim()[0] < 0
    assert "recall" in ax.get_xlabel() and "precision" in ax.get_ylabel()
    plt.close(fig)


def test_the_png_keeps_the_legend_and_is_recognised(tmp_path):
    from PIL import Image

    path = plot_precision_recall(CONFIGS, tmp_path / "pr.png")
    assert is_plot_png(path)
    fig, ax = _figure()
    # the legend stands right of the axes: the saved image is wider than the axes' right
    # edge plus the legend's width (bbox_inches="tight" keeps it)
    width_px = Image.open(path).size[0]
    legend = ax.get_legend().get_window_extent()
    axes = ax.get_window_extent()
    import matplotlib.pyplot as plt

    assert legend.x0 > axes.x1
    assert width_px >= legend.x1 - axes.x0
    plt.close(fig)


def test_the_axes_keep_their_size_however_long_the_legend():
    """Ten methods with long 'given' texts squeezed the axes to a strip beside the legend:
    the figure widens instead."""
    import matplotlib.pyplot as plt

    many = [
        _config(
            f"method {k}",
            "the label list (the map's label names + x.taxonomy.yaml)",
            [(0.5, 0.5)],
            1.0,
            0,
        )
        for k in range(10)
    ]
    widths = []
    for configs in (CONFIGS[:1], many):
        fig = precision_recall_figure(configs)
        fig.canvas.draw()
        widths.append(fig.axes[0].get_window_extent().width)
        plt.close(fig)
    assert widths[1] == pytest.approx(widths[0], rel=0.05)


def _alike(n):
    """Rows that score alike (the antonyms table: every mean at recall ~1, precision
    ~0.05), each a little apart, and one row far from them."""
    rows = [
        _config(f"baseline {k}", "the query alone", [(0.97 + 0.003 * k, 0.03 + 0.004 * k)], 0.0, 0)
        for k in range(n)
    ]
    return [*rows, _config("quash", "the label list", [(0.6, 0.7)], 1.0, 0)]


def test_means_that_overlap_are_shown_apart_in_a_zoom():
    """The antonyms table's means all overlapped at recall ~1: which was which could not
    be read. An inset zooms on them, inside the axes, where they stand apart."""
    import matplotlib.pyplot as plt

    configs = _alike(6)
    fig = precision_recall_figure(configs)
    fig.canvas.draw()
    [ax] = fig.axes
    [inset] = ax.child_axes
    xy = np.array([(c["mean"]["recall"], c["mean"]["precision"]) for c in configs[:-1]])
    (x0, x1), (y0, y1) = inset.get_xlim(), inset.get_ylim()
    assert ((xy[:, 0] > x0) & (xy[:, 0] < x1) & (xy[:, 1] > y0) & (xy[:, 1] < y1)).all()
    # the zoomed area is inside the main axes (its mark and lines stay in the plot)
    (mx0, mx1), (my0, my1) = ax.get_xlim(), ax.get_ylim()
    assert mx0 <= x0 < x1 <= mx1 and my0 <= y0 < y1 <= my1
    # in the inset, the means are further apart than a marker is wide
    shown = inset.transData.transform(xy)
    gaps = np.linalg.norm(shown[:, None] - shown[None], axis=2)[np.triu_indices(len(xy), 1)]
    [size] = {s for col in inset.collections for s in col.get_sizes()}
    assert gaps.min() > np.sqrt(size) * fig.dpi / 72
    # at the plot's own scale they overlapped
    main = ax.transData.transform(xy)
    main_gaps = np.linalg.norm(main[:, None] - main[None], axis=2)[np.triu_indices(len(xy), 1)]
    assert main_gaps.min() < np.sqrt(90) * fig.dpi / 72
    plt.close(fig)


def test_the_zoom_draws_no_tick_label_over_the_axes_labels():
    """The inset sat at 5 % of the axes' width: its own tick labels (four decimals for
    means a thousandth apart) were drawn over the main axes' precision labels."""
    import matplotlib.pyplot as plt

    for r, p in ((0.95, 0.95), (0.5, 0.05), (0.05, 0.5), (0.97, 0.03)):
        configs = [
            _config(f"m{k}", "x", [(r + 0.0007 * k, p + 0.0006 * k)], 0.0, 0) for k in range(3)
        ]
        fig = precision_recall_figure(configs)
        fig.canvas.draw()
        [ax] = fig.axes
        [inset] = ax.child_axes
        renderer = fig.canvas.get_renderer()
        inner = inset.get_tightbbox(renderer)
        for label in [*ax.get_xticklabels(), *ax.get_yticklabels()]:
            box = label.get_window_extent(renderer)
            assert not (label.get_text() and inner.overlaps(box)), label.get_text()
        plt.close(fig)


def test_means_at_the_same_point_are_named_in_the_legend_and_not_zoomed_on():
    """The classifiers table: three rules that match nothing sit at (0, 0) and two that
    answer alike at one point. A zoom on them showed one marker on an axis of
    -0.0100 to 0.0100; which colours lay under the top one could not be read."""
    import matplotlib.pyplot as plt

    configs = [
        _config("svm-rbf", "the label list", [(0.0, 0.0)], 1.0, 1),
        _config("svm-cosine", "the label list", [(0.0, 0.0)], 1.0, 1),
        _config("contrast", "the label list", [(0.6, 0.5)], 0.2, 0),
        _config("lerf-relevancy", "the label list", [(0.6, 0.5)], 0.2, 0),
        _config("nearest", "the label list", [(0.7, 0.75)], 0.2, 0),
    ]
    fig = precision_recall_figure(configs)
    fig.canvas.draw()
    [ax] = fig.axes
    assert ax.child_axes == []  # no two means apart enough for a zoom to show
    texts = [t.get_text() for t in ax.get_legend().get_texts()]
    said = [t for t in texts if "at the same point as" in t]
    assert len(said) == 2
    assert said[0].startswith("svm-cosine") and said[0].endswith("as svm-rbf's")
    assert said[1].startswith("lerf-relevancy") and said[1].endswith("as contrast's")
    assert not any("same point" in t for t in texts if t.startswith(("svm-rbf", "contrast")))
    plt.close(fig)


def test_means_one_thousandth_apart_are_zoomed_on_not_called_the_same():
    import matplotlib.pyplot as plt

    configs = [
        _config("other", "the query alone", [(0.991, 0.049)], 0.0, 0),
        _config("nothing", "the query alone", [(0.990, 0.048)], 0.0, 0),
    ]
    fig = precision_recall_figure(configs)
    fig.canvas.draw()
    assert len(fig.axes[0].child_axes) == 1
    texts = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert not any("same point" in t for t in texts)
    plt.close(fig)


def test_means_apart_get_no_zoom():
    import matplotlib.pyplot as plt

    fig = precision_recall_figure(CONFIGS)
    assert fig.axes[0].child_axes == []
    plt.close(fig)


def test_the_legend_says_what_the_dots_are_when_they_are_not_queries():
    """benchmarks/bench_quality.py plots one dot per seed."""
    import matplotlib.pyplot as plt

    fig = precision_recall_figure(CONFIGS, dots="one seed", mean="mean over the seeds")
    texts = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert texts[-3:] == ["mean over the seeds", "one seed", "iso-F1 curves"]
    plt.close(fig)


def test_a_method_has_the_colour_it_has_in_the_recording(tmp_path):
    """demo.png coloured the methods with matplotlib's tab10, demo.rrd with the viewer's
    palette: the same method had two colours. Past the palette, the marker differs, as in
    the viewer."""
    import matplotlib.pyplot as plt

    rr = pytest.importorskip("rerun")
    from rerun.chunk import RrdReader

    from quash_plugins.viewer import RerunLogger

    configs = [
        _config(f"method {k}", "the query alone", [(0.05 * k, 0.9 - 0.05 * k)], 0.0, 0)
        for k in range(14)
    ]
    out = tmp_path / "e.rrd"
    rec = rr.RecordingStream("quash-eval-test")
    rec.save(out)
    logger = RerunLogger(rec)
    logger.log_evaluation(configs, ["q0"])
    logger.close()
    rec.disconnect()
    logged = {}
    for chunk in RrdReader(out).stream().to_chunks():
        rb = chunk.to_record_batch()
        path = chunk.entity_path.lstrip("/")
        if path.startswith("eval/f1/") and "SeriesLines:colors" in rb.schema.names:
            [[packed]] = rb.column("SeriesLines:colors").to_pylist()
            logged[path.removeprefix("eval/f1/")] = packed  # 0xRRGGBBAA
    fig = precision_recall_figure(configs)
    legend = fig.axes[0].get_legend()
    handles = legend.legend_handles[: len(configs)]
    for k, (c, h) in enumerate(zip(configs, handles)):
        packed = logged[c["name"].replace(" ", "_")]
        want = [(packed >> s & 0xFF) / 255 for s in (24, 16, 8)]
        assert list(h.get_facecolor()[0][:3]) == pytest.approx(want, abs=1e-6), k
    # method 12 has method 0's colour and another marker
    assert handles[12].get_facecolor()[0] == pytest.approx(handles[0].get_facecolor()[0])
    shape = [h.get_paths()[0].vertices.tolist() for h in (handles[0], handles[12])]
    assert shape[0] != shape[1]
    plt.close(fig)
