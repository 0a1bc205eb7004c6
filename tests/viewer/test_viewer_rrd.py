"""RerunLogger and ``quash query --rrd``: read each .rrd back with Rerun's own reader."""

from __future__ import annotations

import re
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
import rerun as rr
from _viewer_maps import make_quash, pixel_map, room_map, voxel_map, write_table_config
from rerun.chunk import RrdReader

from quash_plugins.core.errors import QuashError
from quash_plugins.core.types import Instance, QueryResult
from quash_plugins.viewer import MATCH_COLOR, RerunLogger
from quash_plugins.viewer._display import score_classes


@pytest.fixture(autouse=True)
def _strict():
    rr.set_strict_mode(True)
    yield
    rr.set_strict_mode(False)


def read_rrd(path: Path) -> tuple[RrdReader, dict[str, list]]:
    reader = RrdReader(path)
    by_path: dict[str, list] = defaultdict(list)
    for chunk in reader.stream().to_chunks():
        by_path[chunk.entity_path.lstrip("/")].append(chunk)
    return reader, by_path


def rows(chunks: list, column: str) -> list[tuple[int | None, object]]:
    """(query index or None for static, value) for every row holding ``column``."""
    out = []
    for chunk in chunks:
        rb = chunk.to_record_batch()
        if column not in rb.schema.names:
            continue
        values = rb.column(column).to_pylist()
        times = (
            rb.column("query").to_pylist() if "query" in rb.schema.names else [None] * len(values)
        )
        out += [(t, v) for t, v in zip(times, values) if v is not None]
    return sorted(out, key=lambda tv: -1 if tv[0] is None else tv[0])


def blueprint_views(reader: RrdReader) -> set[tuple[str, str]]:
    """(view class, origin) pairs of the blueprint stored in the file."""
    views = set()
    for store in reader.blueprints():
        for chunk in reader.stream(store=store).to_chunks():
            rb = chunk.to_record_batch()
            if "ViewBlueprint:class_identifier" in rb.schema.names:
                cls = rb.column("ViewBlueprint:class_identifier").to_pylist()
                org = rb.column("ViewBlueprint:space_origin").to_pylist()
                views |= {(c[0], o[0]) for c, o in zip(cls, org)}
    return views


def blueprint_contents(reader: RrdReader) -> set[str]:
    """Every view-content query expression of the stored blueprint."""
    found = set()
    for store in reader.blueprints():
        for chunk in reader.stream(store=store).to_chunks():
            rb = chunk.to_record_batch()
            for name in rb.schema.names:
                if name.startswith("ViewContents:"):
                    for row in rb.column(name).to_pylist():
                        found |= {str(x) for x in (row or [])}
    return found


def log_to_file(path: Path, lmap, results, **options) -> None:
    rec = rr.RecordingStream("quash-test")
    rec.save(path)
    logger = RerunLogger(rec, **options)
    logger.log_map(lmap)
    for i, r in enumerate(results):
        logger.log_result(lmap, r, index=i)
    logger.close()
    rec.disconnect()


def blueprint_columns(reader: RrdReader, column: str) -> list:
    """Every value of a blueprint component column (``"EyeControls3D:position"``...)."""
    out = []
    for store in reader.blueprints():
        for chunk in reader.stream(store=store).to_chunks():
            rb = chunk.to_record_batch()
            if column in rb.schema.names:
                out += [v for v in rb.column(column).to_pylist() if v is not None]
    return out


def blueprint_paths(reader: RrdReader) -> set[str]:
    return {
        chunk.entity_path
        for store in reader.blueprints()
        for chunk in reader.stream(store=store).to_chunks()
    }


def view_names(reader: RrdReader) -> set[str]:
    return {v[0] for v in blueprint_columns(reader, "ViewBlueprint:display_name")}


def test_voxel_map_layout_counts_and_blueprint(tmp_path):
    lmap = voxel_map()
    results = make_quash().query_many(lmap, ["chair", "sofa"])
    # Ground truth is independent of the logger: the chair and sofa blocks.
    assert results[0].mask.tolist() == (lmap.labels == 0).tolist()
    out = tmp_path / "v.rrd"
    log_to_file(out, lmap, results)
    reader, by_path = read_rrd(out)
    assert {"world/map", "world/matches/quash", "world/scores/quash", "queries/quash"} <= set(
        by_path
    )
    assert "world/ceiling" not in by_path  # a 0.3 m block has no ceiling
    # The map: static boxes (voxel map under the box limit), its own colours.
    [(t, centers)] = rows(by_path["world/map"], "Boxes3D:centers")
    assert t is None and len(centers) == lmap.n
    [(_, colors)] = rows(by_path["world/map"], "Boxes3D:colors")
    rgba = np.array(colors, dtype=np.uint32)
    assert ((rgba >> 24) & 255).tolist() == lmap.colors[:, 0].tolist()
    # Matches: only the matched items, at the query's step, in magenta.
    matches = rows(by_path["world/matches/quash"], "Boxes3D:centers")
    assert [t for t, _ in matches] == [0, 1]
    for (_, mask_centers), r in zip(matches, results):
        assert len(mask_centers) == r.n_matched
        np.testing.assert_allclose(np.array(mask_centers), lmap.positions[r.mask], atol=1e-6)
    for _, mc in rows(by_path["world/matches/quash"], "Boxes3D:colors"):
        assert {(c >> 24) & 255 for c in mc} == {MATCH_COLOR[0]}
    # Scores: the geometry once (static), then one class id per item and query.
    [(t, score_centers)] = rows(by_path["world/scores/quash"], "Boxes3D:centers")
    assert t is None and len(score_centers) == lmap.n
    ids = rows(by_path["world/scores/quash"], "Boxes3D:class_ids")
    assert [t for t, _ in ids] == [0, 1]
    for (_, got), r in zip(ids, results):
        assert got == score_classes(r.display_scores, 32).tolist()
    [(_, [context])] = rows(by_path["world/scores"], "AnnotationContext:context")
    assert [c["class_id"] for c in context] == list(range(32))
    labels = [c["class_description"]["info"]["label"] for c in context]
    assert labels[0] == "0.00" and labels[15] == "0.48" and labels[-1] == "1.00 (match)"
    assert [lab.endswith("(match)") for lab in labels] == [i >= 16 for i in range(32)]
    # The document: the query and its config in the title, positives and negatives first.
    docs = rows(by_path["queries/quash"], "TextDocument:text")
    assert [t for t, _ in docs] == [0, 1]
    for (_, [text]), r in zip(docs, results):
        head = text.split("## ")[0]
        assert head.startswith(f"# {r.query} · quash")
        assert "**Positives (1):** " in head and "**Negatives (3):** " in head
        assert "background" in head and "Contrast" in text
        assert f"Presence check: {r.presence}" in head  # "off": this config has none
    # The blueprint names the config in its view titles.
    views = blueprint_views(reader)
    assert ("3D", "world") in views and ("TextDocument", "queries/quash") in views
    assert {"quash: map and matches", "quash: query set"} <= view_names(reader)
    contents = blueprint_contents(reader)
    assert {"+ world/map", "+ world/matches/quash", "+ world/scores/quash/**"} <= contents


def test_per_query_data_is_compact(tmp_path):
    """Static geometry is logged once; a query adds its matches and 2 bytes per item.

    Before, every query re-logged the whole map (positions, sizes and colours of every
    item, about 28 bytes each): a 13-query demo recording was 40 MB.
    """
    lmap = voxel_map(shape=(40, 25, 20))  # 20,000 voxels
    quash = make_quash()
    sizes = {}
    for q in (1, 9):
        results = quash.query_many(lmap, ["chair", "sofa", "chair", "sofa", "chair"][:q] * 2)
        results = results[:q]
        out = tmp_path / f"q{q}.rrd"
        log_to_file(out, lmap, results)
        sizes[q] = out.stat().st_size
        _, by_path = read_rrd(out)
        for path, chunks in by_path.items():
            for t, pos in rows(chunks, "Boxes3D:centers"):
                if t is not None:  # temporal geometry: matches and instances only
                    assert path.startswith(("world/matches", "world/instances")), path
                    assert len(pos) <= max(r.n_matched for r in results)
    per_query = (sizes[9] - sizes[1]) / 8
    assert per_query < 4 * lmap.n, f"{per_query:.0f} bytes per query for {lmap.n} items"


def test_ceiling_is_logged_apart_hidden_and_the_eye_looks_down(tmp_path):
    lmap = room_map()
    results = make_quash().query_many(lmap, ["chair"])
    out = tmp_path / "room.rrd"
    log_to_file(out, lmap, results)
    reader, by_path = read_rrd(out)
    top = lmap.positions[:, 2].max()
    [(_, ceiling)] = rows(by_path["world/ceiling"], "Boxes3D:centers")
    [(_, rest)] = rows(by_path["world/map"], "Boxes3D:centers")
    assert len(ceiling) + len(rest) == lmap.n
    np.testing.assert_allclose([c[2] for c in ceiling], top)
    assert max(c[2] for c in rest) < top
    # Hidden in both 3D views (an EntityBehavior override), still one click away.
    hidden = [p for p in blueprint_paths(reader) if "overrides" in p and "ceiling" in p]
    assert any(p.endswith("overrides/world/ceiling/visualizers") for p in hidden)
    assert blueprint_columns(reader, "EntityBehavior:visible") and all(
        v == [False] for v in blueprint_columns(reader, "EntityBehavior:visible")
    )
    # The eye is above the room, looking down at its floor, z up.
    [[position]] = blueprint_columns(reader, "EyeControls3D:position")[:1]
    [[target]] = blueprint_columns(reader, "EyeControls3D:look_target")[:1]
    [[eye_up]] = blueprint_columns(reader, "EyeControls3D:eye_up")[:1]
    assert position[2] > top + 2.0 and target[2] == pytest.approx(0.0)
    assert eye_up == [0.0, 0.0, 1.0]
    footprint = lmap.positions[:, :2]
    assert (footprint.min(0) <= np.array(target[:2])).all()
    assert (np.array(target[:2]) <= footprint.max(0)).all()
    [(_, coords)] = rows(by_path["world"], "ViewCoordinates:xyz")
    assert coords is not None


def test_configs_get_tabs_and_share_the_query_timeline(tmp_path):
    lmap = voxel_map()
    a = make_quash()
    b = make_quash()
    b.name = "other method"
    rec = rr.RecordingStream("quash-test")
    out = tmp_path / "tabs.rrd"
    rec.save(out)
    logger = RerunLogger(rec)
    for quash in (a, b):
        for i, r in enumerate(quash.query_many(lmap, ["chair", "sofa"])):
            logger.log_result(lmap, r, index=i)
    logger.focus("other method")
    logger.close()
    rec.disconnect()
    reader, by_path = read_rrd(out)
    for c in ("quash", "other_method"):
        assert [t for t, _ in rows(by_path[f"world/matches/{c}"], "Boxes3D:centers")] == [0, 1]
        [(t, [text]), _] = rows(by_path[f"queries/{c}"], "TextDocument:text")
        assert t == 0 and text.startswith("# chair · ")
    assert {"quash: map and matches", "other method: map and matches"} <= view_names(reader)
    # the queries by step, once each (not once per config), in a text log view
    assert rows(by_path["query_list"], "TextLog:text") == [(0, ["chair"]), (1, ["sofa"])]
    assert ("TextLog", "query_list") in blueprint_views(reader)
    # The last blueprint: a Tabs container of one tab per config, focus() the active one.
    containers = {}
    for store in reader.blueprints():
        for chunk in reader.stream(store=store).to_chunks():
            rb = chunk.to_record_batch()
            if "ContainerBlueprint:container_kind" in rb.schema.names:
                names = [n for n in rb.schema.names if n.startswith("ContainerBlueprint:")]
                row = {n: rb.column(n).to_pylist()[-1] for n in names}
                containers[chunk.entity_path.lstrip("/")] = row
    tabs = [
        c
        for c in containers.values()
        if c["ContainerBlueprint:container_kind"] == [1]  # ContainerKind.Tabs
        and len(c["ContainerBlueprint:contents"]) == 2
    ]
    assert len(tabs) == 1
    [active] = tabs[0].get("ContainerBlueprint:active_tab") or [None]
    assert containers[active]["ContainerBlueprint:display_name"] == ["other method"]


def test_points_thinning_and_pca_colours(tmp_path):
    lmap = voxel_map(shape=(10, 8, 4), colors=False)
    results = make_quash().query_many(lmap, ["chair"])
    out = tmp_path / "p.rrd"
    log_to_file(out, lmap, results, max_display_points=100, max_boxes=0)
    _, by_path = read_rrd(out)
    [(_, pos)] = rows(by_path["world/map"], "Points3D:positions")
    assert len(pos) == 100 < lmap.n  # thinned for display ...
    [(_, radii)] = rows(by_path["world/map"], "Points3D:radii")
    assert radii[0] == pytest.approx(0.5 * lmap.voxel_size)
    [(_, colors)] = rows(by_path["world/map"], "Points3D:colors")
    assert len(set(colors)) > 3  # PCA colouring, not one flat colour
    r = results[0]
    assert r.n_matched == int((lmap.labels == 0).sum())  # ... but the query used every item
    [(_, mask_pos)] = rows(by_path["world/matches/quash"], "Points3D:positions")
    assert len(mask_pos) == r.n_matched  # the mask fits under the limit: all drawn
    [(_, ids)] = rows(by_path["world/scores/quash"], "Points3D:class_ids")
    assert len(ids) == 100
    [(_, [text])] = rows(by_path["queries/quash"], "TextDocument:text")
    assert "100 of 320" in text and "display only" in text and "PCA" in text


def test_instances_are_labelled_boxes(tmp_path):
    lmap = voxel_map()
    r = make_quash().query(lmap, "chair")
    idx = np.flatnonzero(r.mask)
    pts = lmap.positions[idx]
    inst = Instance(7, idx, pts.mean(0), pts.min(0), pts.max(0), 0.9)
    r = QueryResult(r.queryset, r.mask, r.scores, r.display_scores, instances=[inst])
    out = tmp_path / "i.rrd"
    log_to_file(out, lmap, [r])
    _, by_path = read_rrd(out)
    [(_, labels)] = rows(by_path["world/instances/quash"], "Boxes3D:labels")
    assert labels == [f"chair #7 ({len(idx)}, 0.90)"]
    [(_, half)] = rows(by_path["world/instances/quash"], "Boxes3D:half_sizes")
    expected = (pts.max(0) - pts.min(0)) / 2 + 0.5 * lmap.voxel_size
    np.testing.assert_allclose(half[0], expected, atol=1e-6)
    [(_, cent)] = rows(by_path["world/instances/quash/centroids"], "Points3D:positions")
    np.testing.assert_allclose(cent[0], pts.mean(0), atol=1e-6)


def test_pixel_map_images_masks_and_2d_blueprint(tmp_path):
    lmap = pixel_map()
    results = make_quash().query_many(lmap, ["chair", "sofa"])
    out = tmp_path / "px.rrd"
    log_to_file(out, lmap, results)
    reader, by_path = read_rrd(out)
    assert not any(p.startswith("world") for p in by_path)  # no positions: no 3D layers
    assert rows(by_path["images"], "AnnotationContext:context")
    for frame in lmap.frames:
        name = frame.frame_id.replace(" ", "_")
        hw = (frame.height, frame.width)
        [(t, [rgb])] = rows(by_path[f"images/{name}/rgb"], "Image:buffer")
        assert t is None and len(rgb) == frame.size * 3
        masks = rows(by_path[f"images/{name}/quash/mask"], "SegmentationImage:buffer")
        assert [t for t, _ in masks] == [0, 1]
        for (_, [buf]), r in zip(masks, results):
            got = np.array(buf, dtype=np.uint8).reshape(hw)
            want = r.mask[frame.offset : frame.offset + frame.size].reshape(hw)
            assert got.tolist() == want.astype(np.uint8).tolist()
            assert got.sum() > 0
        assert len(rows(by_path[f"images/{name}/quash/scores"], "Image:buffer")) == 2
    views = blueprint_views(reader)
    assert ("2D", "images/frame_000") in views and ("2D", "images/frame_001") in views
    assert ("TextDocument", "queries/quash") in views


def test_a_pixel_map_alone_shows_its_images(tmp_path):
    """Before the first result (while quash query --serve-web runs the queries) the layout
    showed one empty 'Query set' document, not the pixel map's images."""
    rec = rr.RecordingStream("quash-test")
    out = tmp_path / "px.rrd"
    rec.save(out)
    logger = RerunLogger(rec)
    logger.log_map(pixel_map())
    logger.close()
    rec.disconnect()
    reader, _ = read_rrd(out)
    assert blueprint_views(reader) == {("2D", "images/frame_000"), ("2D", "images/frame_001")}
    assert blueprint_contents(reader) == {"+ $origin/rgb"}


def test_eval_scalars(tmp_path):
    rec = rr.RecordingStream("quash-eval-test")
    out = tmp_path / "e.rrd"
    rec.save(out)
    logger = RerunLogger(rec)
    logger.log_eval_scalars(
        "svm rbf",
        {"precision": 0.5, "recall": 1.0, "f1": 2 / 3, "iou": 0.5, "note": "text"},
        "chair",
    )
    logger.log_eval_scalars("svm rbf", {"f1": 0.25, "iou": float("nan")}, "sofa")
    logger.log_eval_scalars("contrast", {"f1": 0.1}, "chair")
    logger.close()
    rec.disconnect()
    reader, by_path = read_rrd(out)
    assert rows(by_path["eval/f1/svm_rbf"], "Scalars:scalars") == [
        (0, [pytest.approx(2 / 3)]),
        (1, [0.25]),
    ]
    assert rows(by_path["eval/f1/contrast"], "Scalars:scalars") == [(0, [pytest.approx(0.1)])]
    assert rows(by_path["eval/iou/svm_rbf"], "Scalars:scalars") == [(0, [0.5])]
    assert "eval/note/svm_rbf" not in by_path
    assert rows(by_path["query_list"], "TextLog:text") == [(0, ["chair"]), (1, ["sofa"])]
    views = blueprint_views(reader)
    assert ("TimeSeries", "eval/f1") in views and ("TimeSeries", "eval/iou") in views
    assert ("TextLog", "query_list") in views
    # One colour per config, the same in every metric's plot.
    [(_, f1_color)] = rows(by_path["eval/f1/svm_rbf"], "SeriesLines:colors")
    [(_, iou_color)] = rows(by_path["eval/iou/svm_rbf"], "SeriesLines:colors")
    [(_, other)] = rows(by_path["eval/f1/contrast"], "SeriesLines:colors")
    assert f1_color == iou_color != other


def test_every_config_of_the_demo_has_a_series_colour_of_its_own(tmp_path):
    """The demo plots ten methods: two that shared a colour (the palette had eight) could
    not be told apart in a plot or its legend. Past the palette, the marker differs."""
    rec = rr.RecordingStream("quash-eval-test")
    out = tmp_path / "e.rrd"
    rec.save(out)
    logger = RerunLogger(rec)
    names = [f"method {k}" for k in range(14)]
    for name in names:
        logger.log_eval_scalars(name, {"f1": 0.5}, "chair")
    logger.close()
    rec.disconnect()
    _, by_path = read_rrd(out)
    styles = []
    for name in names:
        chunks = by_path[f"eval/f1/{name.replace(' ', '_')}"]
        [(_, [color])] = rows(chunks, "SeriesLines:colors")
        [(_, [point_color])] = rows(chunks, "SeriesPoints:colors")
        [(_, [marker])] = rows(chunks, "SeriesPoints:markers")
        assert point_color == color
        styles.append((color, marker))
    assert len({color for color, _ in styles[:12]}) == 12
    assert len(set(styles)) == len(names)


def test_eval_legend_sits_beside_the_data(tmp_path):
    """The x axis runs past the last query so the legend (right corner) covers no data."""
    rec = rr.RecordingStream("quash-eval-test")
    out = tmp_path / "e.rrd"
    rec.save(out)
    logger = RerunLogger(rec)
    report = [
        {"name": n, "per_query": {q: {"f1": 0.5, "precision": 1.0} for q in "abcd"}}
        for n in ("one", "two")
    ]
    logger.log_evaluation(report, list("abcd"), "| method | F1 |\n|---|---:|\n| one | 0.5 |")
    logger.close()
    rec.disconnect()
    reader, by_path = read_rrd(out)
    assert [t for t, _ in rows(by_path["eval/f1/one"], "Scalars:scalars")] == [0, 1, 2, 3]
    [(_, [text])] = rows(by_path["summary"], "TextDocument:text")
    assert text.startswith("| method | F1 |")
    ranges = blueprint_columns(reader, "TimeAxis:view_range")
    # Steps 0..3 hold data; the axis runs to 6, leaving the right third to the legend.
    assert ranges == [[{"start": 0, "end": 6}]] * 2  # f1 and precision
    assert ("TextDocument", "summary") in blueprint_views(reader)


def test_configs_whose_names_slug_alike_keep_their_own_entities(tmp_path):
    """Names such as 'my-method' and 'My Method' (or two long names that share 64
    characters) once became one entity path: one tab, one series, the second overwriting the first."""
    lmap = voxel_map()
    long = "quash-labels-" + "x" * 60
    names = ["my-method", "My Method", long + "-a", long + "-b"]
    out = tmp_path / "e.rrd"
    rec = rr.RecordingStream("quash-eval-test")
    rec.save(out)
    logger = RerunLogger(rec)
    for k, name in enumerate(names):
        quash = make_quash()
        quash.name = name
        [r] = quash.query_many(lmap, ["chair"])
        logger.log_result(lmap, r, index=0)
        logger.log_eval_scalars(name, {"f1": k / 10}, "chair")
    logger.close()
    rec.disconnect()
    reader, by_path = read_rrd(out)
    slugs = sorted({p.split("/")[-1] for p in by_path if p.startswith("eval/f1/")})
    assert len(slugs) == len(names)
    f1 = sorted(rows(by_path[f"eval/f1/{s}"], "Scalars:scalars")[0][1][0] for s in slugs)
    assert f1 == pytest.approx([0.0, 0.1, 0.2, 0.3])
    assert all(f"world/matches/{s}" in by_path and f"queries/{s}" in by_path for s in slugs)
    assert {f"{n}: map and matches" for n in names} <= view_names(reader)


def test_eval_scalars_by_query_land_on_its_logged_step(tmp_path):
    """A query string goes to the step where log_result logged that query, not to the
    next number of its own count (sofa's F1 was plotted at chair's step)."""
    lmap = voxel_map()
    out = tmp_path / "e.rrd"
    rec = rr.RecordingStream("quash-eval-test")
    rec.save(out)
    logger = RerunLogger(rec)
    logger.log_map(lmap)
    for i, r in enumerate(make_quash().query_many(lmap, ["chair", "sofa"])):
        logger.log_result(lmap, r, index=i)
    logger.log_eval_scalars("m", {"f1": 0.25}, "sofa")
    logger.log_eval_scalars("m", {"f1": 0.75}, "lamp")  # not logged: the next free step
    logger.log_eval_scalars("m", {"f1": 0.5}, "chair")
    logger.close()
    rec.disconnect()
    _, by_path = read_rrd(out)
    assert rows(by_path["eval/f1/m"], "Scalars:scalars") == [(0, [0.5]), (1, [0.25]), (2, [0.75])]
    names = [(0, ["chair"]), (1, ["sofa"]), (2, ["lamp"])]
    assert rows(by_path["query_list"], "TextLog:text") == names


def test_eval_scalars_by_the_query_as_given_land_on_its_result(tmp_path):
    """The metrics of a query given as the user typed it (``"chair "``, ``"floor  lamp"``)
    land where its result is, under the query's text as run: they went to a new step,
    listed as another query."""
    lmap = voxel_map()
    given = ["chair ", " sofa"]
    results = make_quash().query_many(lmap, given)
    out = tmp_path / "q.rrd"
    rec = rr.RecordingStream("quash-test")
    rec.save(out)
    with RerunLogger(rec) as logger:
        for i, r in enumerate(results):
            logger.log_result(lmap, r, index=i)
        for q in given:
            logger.log_eval_scalars("quash", {"f1": 0.5}, q)
    rec.disconnect()
    _, by_path = read_rrd(out)
    assert [t for t, _ in rows(by_path["eval/f1/quash"], "Scalars:scalars")] == [0, 1]
    listed = rows(by_path["query_list"], "TextLog:text")
    assert listed == [(i, [r.query]) for i, r in enumerate(results)]


def test_evaluation_alone_names_its_steps(tmp_path):
    """`quash eval --rrd` logs no results, only the report: its plots' x axis is the query
    step, so the query list must name the steps, as it does when results are logged."""
    rec = rr.RecordingStream("quash-eval-test")
    out = tmp_path / "e.rrd"
    rec.save(out)
    logger = RerunLogger(rec)
    report = [{"name": "one", "per_query": {q: {"f1": 0.5} for q in ("chair", "sofa")}}]
    logger.log_evaluation(report, ["chair", "sofa"], "| method | F1 |\n|---|---:|\n| one | 0.5 |")
    logger.close()
    rec.disconnect()
    reader, by_path = read_rrd(out)
    assert [t for t, _ in rows(by_path["eval/f1/one"], "Scalars:scalars")] == [0, 1]
    assert rows(by_path["query_list"], "TextLog:text") == [(0, ["chair"]), (1, ["sofa"])]
    assert ("TextLog", "query_list") in blueprint_views(reader)


def test_blueprint_false_leaves_a_robot_recording_its_own_layout(tmp_path):
    """A robot stack's recording (its own camera view) lost its layout to quash's, made
    active: its data was in no view and the time panel on the query timeline. With
    blueprint=False the logger sends no blueprint; with the default it still does."""
    import rerun.blueprint as rrb

    lmap = voxel_map()
    results = make_quash().query_many(lmap, ["chair"])
    for blueprint, want in ((False, {("2D", "robot/camera")}), (True, None)):
        out = tmp_path / f"robot-{blueprint}.rrd"
        rec = rr.RecordingStream("my-robot")
        rec.save(out)
        rec.send_blueprint(rrb.Blueprint(rrb.Spatial2DView(origin="robot/camera")))
        rec.log("robot/camera", rr.Image(np.zeros((4, 6, 3), dtype=np.uint8)), static=True)
        with RerunLogger(rec, blueprint=blueprint) as logger:
            logger.log_result(lmap, results[0], index=0)
        rec.disconnect()
        reader, by_path = read_rrd(out)
        assert "world/matches/quash" in by_path and "robot/camera" in by_path
        if want is not None:
            assert blueprint_views(reader) == want
        else:
            assert ("3D", "world") in blueprint_views(reader)


def test_the_demo_logs_its_scene_before_the_methods_run(tmp_path, monkeypatch):
    """quash demo --serve-web prints its URL first, but logged the scene only once every
    method had run (a minute): the viewer opened meanwhile showed nothing."""
    from quash_plugins.adapters import write_npz_map
    from quash_plugins.demo import runner

    scene = write_npz_map(voxel_map(), tmp_path / "scene.npz")
    monkeypatch.setattr(runner, "demo_scene", lambda *a, **k: scene)
    logged: list[str] = []

    class Viewer:
        def log_map(self, lmap):
            logged.append(f"map {lmap.n}")

    def evaluate(*args, **kwargs):
        logged.append("evaluate")
        raise KeyboardInterrupt  # the rest of the demo is not this test's

    monkeypatch.setattr(runner, "evaluate", evaluate)
    with pytest.raises(KeyboardInterrupt):
        runner.run_demo(viewer=Viewer(), configs=[write_table_config(tmp_path)])
    assert logged == [f"map {voxel_map().n}", "evaluate"]


def test_never_touches_the_global_recording(tmp_path):
    assert rr.get_global_data_recording() is None
    lmap = voxel_map()
    logger = RerunLogger(app_id="mine")
    logger.log_map(lmap)
    logger.close()
    assert rr.get_global_data_recording() is None
    assert rr.get_thread_local_data_recording() is None
    assert logger.recording.get_application_id() == "mine"


def test_what_the_caller_logs_afterwards_is_at_no_query_step(tmp_path):
    """The recording is the caller's (a robot stack's): the logger's ``query`` time must
    not stay set on it, or the robot's own data would be placed at the last query's step
    (and hidden before it on the query timeline). The caller's own timelines stay set."""
    lmap = voxel_map()
    results = make_quash().query_many(lmap, ["chair", "sofa"])
    out = tmp_path / "robot.rrd"
    rec = rr.RecordingStream("my-robot")
    rec.save(out)
    rec.set_time("frame", sequence=7)
    logger = RerunLogger(rec)
    calls = {
        "after_result": lambda: logger.log_result(lmap, results[1], index=1),
        "after_scalars": lambda: logger.log_eval_scalars("m", {"f1": 0.5}, "chair"),
        "after_evaluation": lambda: logger.log_evaluation(
            [{"name": "m", "per_query": {"chair": {"f1": 1.0}}}], ["chair", "sofa"]
        ),
    }
    for name, call in calls.items():
        call()
        rec.log(f"robot/{name}", rr.Points3D([[0.0, 0.0, 0.0]]))
    logger.close()
    rec.disconnect()
    _, by_path = read_rrd(out)
    for name in calls:
        [chunk] = by_path[f"robot/{name}"]
        times = chunk.to_record_batch().schema.names
        assert "query" not in times, name
        assert chunk.to_record_batch().column("frame").to_pylist() == [7], name
    # the logger's own entities are still on the query timeline
    assert [t for t, _ in rows(by_path["world/matches/quash"], "Boxes3D:centers")] == [1]


def test_cli_query_rrd(tmp_path, capsys):
    from quash_plugins.adapters import write_npz_map
    from quash_plugins.cli.main import main

    lmap = voxel_map()
    map_path = write_npz_map(lmap, tmp_path / "map.npz")
    cfg = write_table_config(tmp_path)
    out = tmp_path / "sub" / "out.rrd"
    code = main(["query", str(map_path), "chair", "sofa", "-c", str(cfg), "--rrd", str(out)])
    assert code == 0
    assert out.is_file()
    assert [p.name for p in out.parent.iterdir()] == ["out.rrd"]  # no temp file left
    reader, by_path = read_rrd(out)
    assert reader.recordings()[0].application_id == "quash-query"
    matches = rows(by_path["world/matches/table_contrast"], "Boxes3D:centers")
    for (_, centers), label in zip(matches, (0, 1)):
        assert len(centers) == int((lmap.labels == label).sum())
    assert reader.blueprints()


def test_cli_outputs_given_with_a_tilde_are_written_where_they_were_checked(
    tmp_path, monkeypatch, capsys
):
    """``--rrd=~/q.rrd`` (no shell expands a ``~`` after ``=``): the checks looked at the
    file in the home folder, the recording was written to ``./~/q.rrd``, a folder named
    ``~`` in the current one (as was ``--out``); both now go where they were checked."""
    from quash_plugins.adapters import write_npz_map
    from quash_plugins.cli.main import main

    home, work = tmp_path / "home", tmp_path / "work"
    home.mkdir()
    work.mkdir()
    monkeypatch.setenv("HOME", str(home))
    monkeypatch.chdir(work)
    map_path = write_npz_map(voxel_map(), tmp_path / "map.npz")
    cfg = write_table_config(tmp_path)
    args = ["query", str(map_path), "chair", "-c", str(cfg)]
    assert main([*args, "--rrd=~/q.rrd", "--out=~/r.npz"]) == 0, capsys.readouterr().err
    assert not (work / "~").exists()
    assert (home / "q.rrd").is_file() and (home / "r.npz").is_file()
    reader, _ = read_rrd(home / "q.rrd")
    assert reader.recordings()[0].application_id == "quash-query"
    # the check and the write are of one file: a robot's recording there is kept
    robot = _robot_recording(home / "robot.rrd")
    before = robot.read_bytes()
    assert main([*args, "--rrd=~/robot.rrd"]) == 2
    assert robot.read_bytes() == before


def _robot_recording(path: Path) -> Path:
    """A user's own recording, made by another application."""
    rec = rr.RecordingStream("my-robot")
    rec.save(str(path))
    rec.log("robot/pose", rr.Points3D([[0.0, 0.0, 0.0]]))
    rec.flush()
    rec.disconnect()
    return path


def test_cli_rrd_replaces_only_quash_recordings_without_force(tmp_path, capsys):
    """A recording of another application id (a robot's own log) is never replaced
    without --force; a previous quash recording is."""
    import hashlib

    from quash_plugins.adapters import write_npz_map
    from quash_plugins.cli.main import main

    map_path = write_npz_map(voxel_map(), tmp_path / "map.npz")
    cfg = write_table_config(tmp_path)
    robot = _robot_recording(tmp_path / "robot.rrd")
    assert RrdReader(robot).recordings()[0].application_id == "my-robot"
    before = hashlib.sha256(robot.read_bytes()).hexdigest()
    argv = ["-q", "query", str(map_path), "chair", "-c", str(cfg), "--rrd", str(robot)]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert str(robot) in err and "'my-robot'" in err and "--force" in err
    assert hashlib.sha256(robot.read_bytes()).hexdigest() == before
    assert main([*argv, "--force"]) == 0
    assert RrdReader(robot).recordings()[0].application_id == "quash-query"
    assert main(argv) == 0  # now a previous quash recording: replaced without --force
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "map.npz",
        "quash.yaml",
        "robot.rrd",
        "table.npz",
    ]


def test_cli_connect_confirms_what_it_streamed(tmp_path, capsys):
    """--connect to a listening viewer (here a gRPC server in this process) says where
    the recording went, as --rrd says 'wrote FILE'."""
    import socket

    from quash_plugins.adapters import write_npz_map
    from quash_plugins.cli.main import main

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    server = rr.RecordingStream("a-viewer")
    server.set_sinks(rr.GrpcServerSink(bind_ip="127.0.0.1", port=port))
    url = f"rerun+http://127.0.0.1:{port}/proxy"
    try:
        map_path = write_npz_map(voxel_map(), tmp_path / "map.npz")
        cfg = write_table_config(tmp_path)
        assert main(["query", str(map_path), "chair", "-c", str(cfg), "--connect", url]) == 0
    finally:
        server.disconnect()
    assert f"streamed to the Rerun viewer at {url}" in capsys.readouterr().err


def test_cli_rejects_bad_rrd_name(tmp_path):
    from quash_plugins.adapters import write_npz_map
    from quash_plugins.cli.main import main

    map_path = write_npz_map(voxel_map(), tmp_path / "map.npz")
    cfg = write_table_config(tmp_path)
    code = main(["query", str(map_path), "chair", "-c", str(cfg), "--rrd", str(tmp_path / "x.txt")])
    assert code == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["map.npz", "quash.yaml", "table.npz"]


@pytest.mark.parametrize("command", ["query", "eval"])
@pytest.mark.parametrize(
    "flag, value, said",
    [
        ("--rrd", "out", "--rrd out: the file name must end in .rrd"),
        ("--connect", "http://127.0.0.1:9876/proxy", "expected a URL like rerun+http"),
    ],
)
def test_cli_refuses_a_bad_rrd_name_or_viewer_url_before_reading_the_map(
    command, flag, value, said, tmp_path, capsys
):
    """Both were refused only once the map was read (a large map: after a long wait); a
    map that cannot be read shows they are now refused first."""
    from quash_plugins.cli.main import main

    broken = tmp_path / "map.npz"
    broken.write_bytes(b"not a map")
    cfg = write_table_config(tmp_path)
    args = [command, str(broken), *(["chair"] if command == "query" else ["--all-labels"])]
    assert main([*args, "-c", str(cfg), flag, value]) == 2
    assert said in capsys.readouterr().err


@pytest.mark.parametrize(
    "opts",
    [
        {"grpc_port": 0},
        {"web_port": 70000},
        {"bind": "localhost6.invalid"},
        {"bind": "999.0.0.1"},
        {"bind": "::1"},
        {"web_port": 9090, "grpc_port": 9090},
    ],
)
def test_sink_logger_refuses_bad_ports_and_addresses(opts, tmp_path):
    """The Python API checks them too: port 0 is not the default port in disguise."""
    from quash_plugins.core.errors import UsageError
    from quash_plugins.viewer import SinkRerunLogger, ViewerOptions

    rrd = tmp_path / "x.rrd"
    with pytest.raises(UsageError, match="not a port number|not an IP address|IPv6|a port each"):
        SinkRerunLogger(ViewerOptions(rrd=rrd, serve_web=True, **opts))
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("quiet", [False, True])
def test_a_quiet_sink_does_not_announce_its_file(quiet, tmp_path, capsys):
    """``quash -q ... --rrd F`` printed "wrote F" all the same: ViewerOptions(quiet=True)
    (the CLI's --quiet) writes the recording and says nothing of it."""
    from quash_plugins.adapters import write_npz_map
    from quash_plugins.cli.main import main
    from quash_plugins.viewer import SinkRerunLogger, ViewerOptions

    rrd = tmp_path / "x.rrd"
    logger = SinkRerunLogger(ViewerOptions(rrd=rrd, quiet=quiet), app_id="quash-query")
    logger.log_map(voxel_map())
    logger.close()
    assert rrd.is_file()
    assert (f"wrote {rrd}" in capsys.readouterr().err) is not quiet
    # and the CLI hands its --quiet to the sinks
    cfg = write_table_config(tmp_path)
    map_path = write_npz_map(voxel_map(), tmp_path / "map.npz")
    out = tmp_path / "q.rrd"
    args = ["query", str(map_path), "chair", "-c", str(cfg), "--rrd", str(out)]
    assert main((["-q"] if quiet else []) + args) == 0
    assert out.is_file()
    assert (f"wrote {out}" in capsys.readouterr().err) is not quiet


def test_cli_query_rrd_per_image_feature_map(tmp_path):
    pytest.importorskip("PIL")
    from PIL import Image

    from quash_plugins.cli.main import main
    from quash_plugins.core import registry

    if "image-features" not in registry.available("adapters"):
        pytest.skip("the image-features adapter is not installed")
    lmap = pixel_map()
    folder = tmp_path / "saved-feat"
    folder.mkdir()
    emb = np.asarray(lmap.embeddings)
    rng = np.random.default_rng(3)
    for i, frame in enumerate(lmap.frames):
        block = emb[frame.offset : frame.offset + frame.size]
        np.save(folder / f"frame{i:06d}.npy", block.reshape(frame.height, frame.width, -1))
        rgb = rng.integers(0, 255, (frame.height, frame.width, 3), dtype=np.uint8)
        Image.fromarray(rgb).save(folder / f"frame{i:06d}.png")
    cfg = write_table_config(tmp_path)
    out = tmp_path / "px.rrd"
    code = main(
        [
            "query",
            str(folder),
            "chair",
            "sofa",
            "-c",
            str(cfg),
            "--adapter",
            "image-features",
            "--rrd",
            str(out),
        ]
    )
    assert code == 0
    reader, by_path = read_rrd(out)
    for i, frame in enumerate(lmap.frames):
        name = f"frame{i:06d}"
        [(_, [rgb])] = rows(by_path[f"images/{name}/rgb"], "Image:buffer")
        want_rgb = np.asarray(Image.open(folder / f"{name}.png")).ravel().tolist()
        assert rgb == want_rgb
        masks = rows(by_path[f"images/{name}/table_contrast/mask"], "SegmentationImage:buffer")
        labels = lmap.labels[frame.offset : frame.offset + frame.size]
        for (t, [buf]), label in zip(masks, (0, 1)):
            assert (np.array(buf) == 1).tolist() == (labels == label).tolist(), (t, label)
        # Instances come from quash_plugins.engine.instances (connected pixels per frame).
        boxes = rows(by_path[f"images/{name}/table_contrast/instances"], "Boxes2D:labels")
        assert [t for t, _ in boxes] == [0, 1] and all(labels for _, labels in boxes)
        # labelled as the 3D boxes are: the query, the id, the size and the mean score
        [chair_box] = boxes[0][1]
        assert re.fullmatch(r"chair #\d+ \(6, -?\d+\.\d\d\)", chair_box), chair_box
        # The chair block of frame i covers rows 1..2 and columns 1+i..3+i.
        inst = by_path[f"images/{name}/table_contrast/instances"]
        [(_, half), _] = rows(inst, "Boxes2D:half_sizes")
        [(_, centers), _] = rows(inst, "Boxes2D:centers")
        assert half == [[1.5, 1.0]] and centers == [[2.5 + i, 2.0]]
    views = blueprint_views(reader)
    assert ("2D", "images/frame000000") in views


def test_recording_size_paragraph_describes_todays_demo():
    """docs/rerun.md gives the size of the demo's recording for a number of methods and
    queries: they must be the demo's own (it once said 6 methods when the demo ran 10)."""
    import re

    from quash_plugins.demo.runner import DEMO_ABSENT, DEMO_CONFIGS, DEMO_QUERIES

    doc = (Path(__file__).resolve().parents[2] / "docs" / "rerun.md").read_text()
    found = re.search(r"`quash demo` \(51k voxels, (\d+) methods, (\d+) queries\)", doc)
    assert found, "the recording-size paragraph of docs/rerun.md changed shape"
    assert int(found[1]) == len(DEMO_CONFIGS)
    assert int(found[2]) == len(DEMO_QUERIES) + len(DEMO_ABSENT)


def test_items_the_presence_check_dropped_are_shown_grey(tmp_path):
    """world/rejected/<config> holds exactly the dropped items, grey, at the query's step;
    a query with nothing dropped clears it; the document says how many."""
    import dataclasses

    from quash_plugins.viewer._log_result import REJECTED_COLOR

    lmap = voxel_map()
    chair, sofa = make_quash().query_many(lmap, ["chair", "sofa"])
    dropped = lmap.labels == 1  # say the check dropped the sofa block for "chair"
    chair = dataclasses.replace(chair, rejected=dropped)
    sofa = dataclasses.replace(sofa, rejected=np.zeros(lmap.n, bool))
    out = tmp_path / "r.rrd"
    log_to_file(out, lmap, [chair, sofa])
    reader, by_path = read_rrd(out)
    [(t, centers)] = rows(by_path["world/rejected/quash"], "Boxes3D:centers")
    assert t == 0
    np.testing.assert_allclose(np.array(centers), lmap.positions[dropped], atol=1e-6)
    for _, colors in rows(by_path["world/rejected/quash"], "Boxes3D:colors"):
        assert {(c >> 24) & 255 for c in colors} == {REJECTED_COLOR[0]}
    texts = [str(v[0]) for _, v in rows(by_path["queries/quash"], "TextDocument:text")]
    assert f"dropped {int(dropped.sum()):,} matched items (grey in the map view)" in texts[0]
    assert "dropped" not in texts[1]
    assert "+ world/rejected/quash" in blueprint_contents(reader)


def _eye(reader):
    return [blueprint_columns(reader, f"EyeControls3D:{k}")[0][0] for k in ("position", "eye_up")]


def test_the_up_axis_comes_from_the_map_unless_given(tmp_path):
    """A y-up map (a VLMaps camera-base map records ``source["up"] = "+y"``) is seen from
    above along y, its ceiling found on y; an explicit ``up`` still wins."""
    zup = room_map()
    yup = room_map()
    x, y, z = np.asarray(zup.positions, dtype=np.float32).T
    yup.positions = np.column_stack([x, z, -y])  # the same room, rotated to y up
    yup.source = {**yup.source, "up": "+y"}
    top = float(yup.positions[:, 1].max())
    results = make_quash().query_many(yup, ["chair"])

    log_to_file(tmp_path / "auto.rrd", yup, results)  # up="auto", the default
    reader, by_path = read_rrd(tmp_path / "auto.rrd")
    [(_, ceiling)] = rows(by_path["world/ceiling"], "Boxes3D:centers")
    np.testing.assert_allclose([c[1] for c in ceiling], top)
    position, eye_up = _eye(reader)
    assert eye_up == [0.0, 1.0, 0.0] and position[1] > top + 2.0
    [(_, coords)] = rows(by_path["world"], "ViewCoordinates:xyz")
    assert coords == rr.ViewCoordinates.RIGHT_HAND_Y_UP.as_arrow_array().to_pylist()

    log_to_file(tmp_path / "z.rrd", yup, results, up="+z")  # the caller's axis wins
    reader, by_path = read_rrd(tmp_path / "z.rrd")
    assert _eye(reader)[1] == [0.0, 0.0, 1.0]
    [(_, coords)] = rows(by_path["world"], "ViewCoordinates:xyz")
    assert coords == rr.ViewCoordinates.RIGHT_HAND_Z_UP.as_arrow_array().to_pylist()

    log_to_file(tmp_path / "plain.rrd", zup, results)  # a map that does not say: +z
    assert _eye(read_rrd(tmp_path / "plain.rrd")[0])[1] == [0.0, 0.0, 1.0]
    with pytest.raises(QuashError, match="'sideways'"):
        RerunLogger(rr.RecordingStream("quash-test"), up="sideways")


def test_cli_up_orients_a_map_whose_format_does_not_say(tmp_path, capsys):
    """``--up`` (query, eval, demo): a y-up cloud in an NPZ, which records no up axis."""
    from quash_plugins.adapters import write_npz_map
    from quash_plugins.cli.main import build_parser, main, subcommand_parsers

    lmap = room_map()
    x, y, z = np.asarray(lmap.positions, dtype=np.float32).T
    lmap.positions = np.column_stack([x, -z, y])  # y down, as camera frames are
    map_path = write_npz_map(lmap, tmp_path / "map.npz")
    cfg = write_table_config(tmp_path)
    argv = ["-q", "query", str(map_path), "chair", "-c", str(cfg), "--rrd"]
    for flags, eye_up in (([], [0.0, 0.0, 1.0]), (["--up=-y"], [0.0, -1.0, 0.0])):
        out = tmp_path / f"up{len(flags)}.rrd"
        assert main([*argv, str(out), *flags]) == 0
        assert _eye(read_rrd(out)[0])[1] == eye_up
    with pytest.raises(SystemExit) as exited:
        main([*argv, str(tmp_path / "bad.rrd"), "--up", "sideways"])
    assert exited.value.code == 2
    assert "--up" in capsys.readouterr().err and not (tmp_path / "bad.rrd").exists()
    ev = tmp_path / "eval.rrd"
    argv = ["-q", "eval", str(map_path), "-c", str(cfg), "--queries", "chair", "--rrd", str(ev)]
    assert main([*argv, "--up=-y"]) == 0
    assert _eye(read_rrd(ev)[0])[1] == [0.0, -1.0, 0.0]
    parsers = subcommand_parsers(build_parser())
    for command in ("query", "eval", "demo"):  # eval logs the map with its results
        [up] = [a for a in parsers[command]._actions if "--up" in a.option_strings]
        assert up.default == "auto" and set(up.choices) == {
            "auto",
            "+x",
            "-x",
            "+y",
            "-y",
            "+z",
            "-z",
        }


def test_pixels_the_presence_check_dropped_are_grey_in_the_image_masks(tmp_path):
    """A pixel map has no map view: the dropped pixels are class 2 of each frame's mask
    (grey, named in the images' annotation context), and the document says so."""
    import dataclasses

    from quash_plugins.viewer._log_result import REJECTED_COLOR

    lmap = pixel_map()
    chair, sofa = make_quash().query_many(lmap, ["chair", "sofa"])
    dropped = (lmap.labels == 1) & ~chair.mask  # say the check dropped the sofa pixels
    assert dropped.any()
    chair = dataclasses.replace(chair, rejected=dropped)
    sofa = dataclasses.replace(sofa, rejected=None)
    out = tmp_path / "px.rrd"
    log_to_file(out, lmap, [chair, sofa])
    _, by_path = read_rrd(out)
    [(_, [context])] = rows(by_path["images"], "AnnotationContext:context")
    classes = {c["class_id"]: c["class_description"]["info"] for c in context}
    assert (classes[2]["color"] >> 24) & 255 == REJECTED_COLOR[0]
    assert "presence" in classes[2]["label"]
    for frame in lmap.frames:
        name = frame.frame_id.replace(" ", "_")
        hw = (frame.height, frame.width)
        sl = slice(frame.offset, frame.offset + frame.size)
        masks = rows(by_path[f"images/{name}/quash/mask"], "SegmentationImage:buffer")
        first, second = (np.array(buf, dtype=np.uint8).reshape(hw) for _, [buf] in masks)
        want = chair.mask[sl].astype(np.uint8) + 2 * dropped[sl].astype(np.uint8)
        assert first.tolist() == want.reshape(hw).tolist()
        assert second.tolist() == sofa.mask[sl].astype(np.uint8).reshape(hw).tolist()
    texts = [str(v[0]) for _, v in rows(by_path["queries/quash"], "TextDocument:text")]
    n = int(dropped.sum())
    assert f"dropped {n:,} matched item{'s' if n > 1 else ''} (grey in the image masks)" in texts[0]
    assert "map view" not in texts[0]


def test_cli_eval_rrd_plots_ap_and_the_absence_queries(tmp_path):
    """`quash eval --rrd`: each present query's AP beside F1, and each absence query at
    its own step after them (named in the query list) as `absence`, 1 when the config's
    mask came back empty, else 0: the same numbers as the report's JSON."""
    import json

    from quash_plugins.adapters import write_npz_map
    from quash_plugins.cli.main import main

    lmap = voxel_map()
    map_path = write_npz_map(lmap, tmp_path / "map.npz")
    cfg = write_table_config(tmp_path)
    out, js = tmp_path / "e.rrd", tmp_path / "e.json"
    args = ["eval", str(map_path), "-c", str(cfg), "--queries", "chair,sofa"]
    code = main([*args, "--absent", "nothing,background", "--rrd", str(out), "--json", str(js)])
    assert code == 0
    [report] = json.loads(js.read_text())["configs"]
    reader, by_path = read_rrd(out)
    names = [(t, v[0]) for t, v in rows(by_path["query_list"], "TextLog:text")]
    assert names == [(0, "chair"), (1, "sofa"), (2, "nothing"), (3, "background")]
    ap = rows(by_path["eval/ap/table_contrast"], "Scalars:scalars")
    assert ap == [
        (i, [pytest.approx(report["per_query"][q]["ap"])]) for i, q in enumerate(["chair", "sofa"])
    ]
    absence = rows(by_path["eval/absence/table_contrast"], "Scalars:scalars")
    want = [float(report["absence"]["per_query"][q]["empty"]) for q in ("nothing", "background")]
    assert absence == [(2, [want[0]]), (3, [want[1]])]
    assert ("TimeSeries", "eval/absence") in blueprint_views(reader)
    assert ("TimeSeries", "eval/ap") in blueprint_views(reader)


def _near_threshold_result(lmap):
    """A chair result whose display scores cover [0, 1] evenly, with the scores just
    below and at the threshold's 0.5; a match is a raw score above the threshold (0.5
    on the display scale), as the engine decides it."""
    import dataclasses

    [r] = make_quash().query_many(lmap, ["chair"])
    display = np.linspace(0.0, 1.0, lmap.n, dtype=np.float32)
    below = np.nextafter(np.float32(0.5), np.float32(0.0))
    display[:6] = [0.45, 0.47, 0.4999, below, 0.5, 0.55]
    scores = display - np.float32(0.5)
    return dataclasses.replace(
        r, display_scores=display, scores=scores, mask=scores > 0, threshold=0.0
    )


@pytest.mark.parametrize("k", [2, 3, 5, 6, 11, 32, 33])
def test_only_scores_at_or_above_the_threshold_are_in_a_match_class(k, tmp_path):
    """score_classes=11 put the display scores from 0.45 to 0.5 in class 5, labelled
    '0.50 (match)': 95 unmatched items carried a match colour. The threshold is a class
    boundary for every class count, odd or even."""
    lmap = voxel_map()
    r = _near_threshold_result(lmap)
    out = tmp_path / "k.rrd"
    log_to_file(out, lmap, [r], score_classes=k)
    _, by_path = read_rrd(out)
    [(_, [context])] = rows(by_path["world/scores"], "AnnotationContext:context")
    labels = {c["class_id"]: c["class_description"]["info"]["label"] for c in context}
    assert sorted(labels) == list(range(k))
    match_classes = {i for i, label in labels.items() if label.endswith("(match)")}
    assert match_classes == set(range(min(match_classes), k))  # the top classes
    [(_, ids)] = rows(by_path["world/scores/quash"], "Boxes3D:class_ids")
    in_match_class = np.isin(np.array(ids), list(match_classes))
    display = r.display_scores
    assert not (in_match_class & (display < 0.5)).any(), "a non-match in a '(match)' class"
    assert (in_match_class == (display >= 0.5)).all()
    assert in_match_class[r.mask].all()  # every match is in a match class
    for i in set(ids):  # each class holds scores around its label's value
        held = display[np.array(ids) == i]
        value = float(labels[i].split()[0])
        assert held.min() - 0.5 / (k - 1) - 0.01 <= value <= held.max() + 0.5 / (k - 1) + 0.01


def test_the_default_score_classes_are_the_rounded_display_score():
    """32 classes (the default) were already right: the threshold falls between classes
    15 and 16, so nothing changes for them, down to the float32 neighbours of 0.5."""
    half = np.float32(0.5)
    around = [half]
    for direction in (0.0, 1.0):
        v = half
        for _ in range(64):
            v = np.nextafter(v, np.float32(direction))
            around.append(v)
    values = np.concatenate([np.linspace(0, 1, 100_001, dtype=np.float32), around])
    want = np.rint(values * np.float32(31)).astype(np.uint16)
    assert score_classes(values, 32).tolist() == want.tolist()


def test_a_second_query_at_a_step_in_use_is_refused_naming_both(tmp_path):
    """Two query_many calls each logged from index=0: the second's rows went to the
    first's steps and the query list kept only the first's names, so the viewer showed
    'sofa' under the name 'chair'. Now the second query is refused before anything of it
    is logged, saying which step, which queries and which index to use."""
    lmap = voxel_map()
    quash = make_quash()
    [chair] = quash.query_many(lmap, ["chair"])
    [sofa] = quash.query_many(lmap, ["sofa"])
    other = make_quash()
    other.name = "other method"
    [other_chair] = other.query_many(lmap, ["chair"])
    out = tmp_path / "s.rrd"
    rec = rr.RecordingStream("quash-test")
    rec.save(out)
    logger = RerunLogger(rec)
    logger.log_result(lmap, chair, index=0)
    logger.log_result(lmap, other_chair, index=0)  # the same query in another config: fine
    with pytest.raises(QuashError) as refused:
        logger.log_result(lmap, sofa, index=0)
    said = str(refused.value)
    assert "step 0" in said and "'chair'" in said and "'sofa'" in said
    assert "index=1" in said
    logger.log_result(lmap, sofa, index=1)  # as the message says
    with pytest.raises(QuashError, match="log_evaluation: step 0 .* 'chair'"):
        logger.log_evaluation([{"name": "quash", "per_query": {}}], ["sofa", "chair"])
    logger.close()
    rec.disconnect()
    _, by_path = read_rrd(out)
    assert rows(by_path["query_list"], "TextLog:text") == [(0, ["chair"]), (1, ["sofa"])]
    matches = rows(by_path["world/matches/quash"], "Boxes3D:centers")
    assert [t for t, _ in matches] == [0, 1]
    assert [len(c) for _, c in matches] == [chair.n_matched, sofa.n_matched]
    docs = rows(by_path["queries/quash"], "TextDocument:text")
    assert [(t, text.split(" · ")[0]) for t, [text] in docs] == [(0, "# chair"), (1, "# sofa")]


@pytest.mark.parametrize("second", ["room", "same source, other items"])
def test_a_second_map_is_refused_and_the_first_kept(second, tmp_path):
    """world/map and the score geometry are static: a second map replaced the first
    one's at every step, and the first map's matches were drawn over the second."""
    map1 = voxel_map()
    map2 = room_map() if second == "room" else voxel_map(shape=(7, 5, 3))
    r1 = make_quash().query(map1, "chair")
    r2 = make_quash().query(map2, "chair")
    out = tmp_path / "m.rrd"
    rec = rr.RecordingStream("quash-test")
    rec.save(out)
    logger = RerunLogger(rec)
    logger.log_result(map1, r1, index=0)
    with pytest.raises(QuashError) as refused:
        logger.log_result(map2, r2, index=1)
    said = str(refused.value)
    assert "another map" in said and "RerunLogger" in said and "recording" in said
    with pytest.raises(QuashError, match="another map"):
        logger.log_map(map2)
    logger.close()
    rec.disconnect()
    _, by_path = read_rrd(out)
    [(t, centers)] = rows(by_path["world/map"], "Boxes3D:centers")
    assert t is None and len(centers) == map1.n
    [(t, centers)] = rows(by_path["world/scores/quash"], "Boxes3D:centers")
    assert t is None and len(centers) == map1.n
    assert [t for t, _ in rows(by_path["world/matches/quash"], "Boxes3D:centers")] == [0]
    assert "world/ceiling" not in by_path  # the room's


def test_the_same_map_again_is_logged_once_and_keeps_every_tab(tmp_path):
    """The same object, or the same map read again (another object with the same source
    and contents), logs nothing new: the static layers once, and the tabs of the configs
    logged before stay (a second log_map used to drop them from the blueprint)."""
    lmap = voxel_map()
    again = voxel_map()  # read again: the same source and contents, another object
    assert again is not lmap and again.source == lmap.source
    other = make_quash()
    other.name = "other method"
    out = tmp_path / "m.rrd"
    rec = rr.RecordingStream("quash-test")
    rec.save(out)
    logger = RerunLogger(rec)
    logger.log_map(lmap)
    logger.log_map(lmap)
    for i, r in enumerate(make_quash().query_many(lmap, ["chair", "sofa"])):
        logger.log_result(lmap, r, index=i)
    for i, r in enumerate(other.query_many(again, ["chair", "sofa"])):
        logger.log_result(again, r, index=i)
    logger.close()
    rec.disconnect()
    reader, by_path = read_rrd(out)
    [(t, centers)] = rows(by_path["world/map"], "Boxes3D:centers")
    assert t is None and len(centers) == lmap.n
    for c in ("quash", "other_method"):
        [(t, _)] = rows(by_path[f"world/scores/{c}"], "Boxes3D:centers")
        assert t is None
        assert [t for t, _ in rows(by_path[f"world/matches/{c}"], "Boxes3D:centers")] == [0, 1]
    assert {"quash: map and matches", "other method: map and matches"} <= view_names(reader)
