"""The Markdown query document shown beside the 3D view (``viewer/_document.py``)."""

from __future__ import annotations

from _viewer_maps import TABLE, voxel_map

from quash_plugins.core import registry
from quash_plugins.encoders import TableEncoder
from quash_plugins.engine.pipeline import Quash
from quash_plugins.viewer._document import queryset_markdown


def _result(**options):
    quash = Quash(
        TableEncoder(table=TABLE),
        classifier=registry.create("classifiers", "contrast"),
        cache=False,
        **options,
    )
    lmap = voxel_map()
    return lmap, quash.query_many(lmap, ["chair"])[0]


def test_document_says_instances_off_when_the_config_groups_none():
    lmap, off = _result(instances=None)
    text = queryset_markdown(lmap, off, 0)
    assert "instances: off" in text and "0 instances" not in text
    lmap, on = _result(instances=True)
    assert on.instances
    n = len(on.instances)
    assert f"· {n} instance{'' if n == 1 else 's'} ·" in queryset_markdown(lmap, on, 0)


def test_document_times_presence_before_the_total_and_folds_the_group_sizes():
    import numpy as np

    from quash_plugins.core.types import QueryResult, QuerySet

    lmap = voxel_map()
    qs = QuerySet("bed", ["bed"], ["sofa", "chair", "other"], {"negative_groups": [1, 1]})
    n = lmap.n
    result = QueryResult(
        qs,
        np.zeros(n, bool),
        np.zeros(n, np.float32),
        np.zeros(n, np.float32),
        timings={"classify": 0.01, "presence": 0.002, "total": 0.012},
    )
    text = queryset_markdown(lmap, result, 0)
    assert text.index("| presence |") < text.index("| total |")
    assert "negative_groups: [1, 1]" in text


def _absent_bed(lmap, rejected, presence):
    import numpy as np

    from quash_plugins.core.types import QueryResult, QuerySet

    qs = QuerySet("bed", ["bed"], ["sofa", "chair", "other"], {"presence": presence})
    n = lmap.n
    zeros = np.zeros(n, np.float32)
    return QueryResult(qs, np.zeros(n, bool), zeros, zeros, rejected=rejected)


def test_document_names_what_the_dropped_items_are_by_the_maps_labels():
    """An absent query's look-alikes by name: the labels of the items the presence check
    dropped, most first, with their counts (the map's own labels, not the classifier's)."""
    from collections import Counter

    import numpy as np

    lmap = voxel_map()
    rng = np.random.default_rng(4)
    rejected = rng.random(lmap.n) < 0.4
    rejected[lmap.labels == 0] = True  # every chair cell: chair has the most
    absent = {"checked": True, "present": False, "components": 3, "kept": 0}
    text = queryset_markdown(lmap, _absent_bed(lmap, rejected, absent), 0)
    counts = Counter(lmap.label_names[i] for i in lmap.labels[rejected])
    want = ", ".join(f"{name} {n:,}" for name, n in counts.most_common())
    assert f"Dropped items by the map's labels: {want}" in text
    assert "Closest competitor" not in text  # an absent decision names its own
    # nothing dropped, or a map without labels: no line
    none = queryset_markdown(lmap, _absent_bed(lmap, np.zeros(lmap.n, bool), absent), 0)
    assert "Dropped items" not in none
    lmap.labels = None
    assert "Dropped items" not in queryset_markdown(lmap, _absent_bed(lmap, rejected, absent), 0)


def test_document_names_a_present_objects_closest_competitor():
    import numpy as np

    lmap = voxel_map()
    present = {"checked": True, "present": True, "components": 2, "kept": 1, "rival": "sofa"}
    text = queryset_markdown(lmap, _absent_bed(lmap, np.zeros(lmap.n, bool), present), 0)
    assert "Closest competitor: sofa" in text
    assert text.index("Closest competitor") < text.index("**Positives")


def test_document_counts_the_labels_past_the_first_ones():
    import numpy as np

    from quash_plugins.viewer._document import LOOKALIKE_LABELS

    lmap = voxel_map()
    n_labels = LOOKALIKE_LABELS + 3
    lmap.labels = np.arange(lmap.n) % n_labels - 1  # -1: unlabelled items too
    lmap.label_names = [f"thing{i}" for i in range(n_labels - 1)]
    absent = {"checked": True, "present": False, "components": 1, "kept": 0}
    text = queryset_markdown(lmap, _absent_bed(lmap, np.ones(lmap.n, bool), absent), 0)
    [line] = [x for x in text.splitlines() if x.startswith("Dropped items")]
    named = n_labels - 1
    assert line.endswith(f"… and {named - LOOKALIKE_LABELS} more labels")
    assert line.count("thing") == LOOKALIKE_LABELS
    assert f"unlabelled {int((lmap.labels < 0).sum())}" in line


def test_document_says_which_scale_its_threshold_is_on():
    """The raw threshold (0 for most classifiers) beside the score view's "0.5 =
    threshold" read as two thresholds: the document says which scale each is on."""
    lmap, result = _result()
    text = queryset_markdown(lmap, result, 0)
    assert f"threshold {result.threshold:g} on its raw scores (0.5 in the score colours)" in text


def test_document_of_an_answer_nothing_scored_for_says_by_how_much():
    """The presence check off and a hand-set threshold over every score: the document
    said "Matched 0" and "Presence check: off", not why; it now gives the best score and
    the threshold it missed, as `quash query` prints."""
    lmap, matched = _result(instances=None)
    assert matched.n_matched and matched.presence == "off"
    assert "Nothing matched" not in queryset_markdown(lmap, matched, 0)
    best = float(matched.scores.max())
    lmap, empty = _result(instances=None, threshold=best + 1.0)
    assert empty.n_matched == 0
    text = queryset_markdown(lmap, empty, 0)
    want = f"Nothing matched: its highest score is {best:.3g}, under the threshold {best + 1:g}"
    assert want in text
    assert text.index("Nothing matched") < text.index("Presence check")


def test_document_of_an_absent_object_leaves_the_reason_to_the_presence_line():
    import numpy as np

    lmap = voxel_map()
    absent = {"checked": True, "present": False, "components": 3, "kept": 0}
    result = _absent_bed(lmap, np.ones(lmap.n, bool), absent)
    assert result.emptied_by_presence is not None and result.under_threshold is None
    assert "Nothing matched" not in queryset_markdown(lmap, result, 0)


def test_document_of_a_live_vlmap_names_it():
    """A query on a live VLMaps ``VLMap`` (``patch_vlmap``, ``Quash.query(vlmap, ...)``)
    logged to Rerun said only "voxels map <memory>" under Map; it names the live object
    and the adapter that read it, as the log line does."""
    import numpy as np

    class VLMap:  # what VLMaps' VLMap holds after load_map (mobile base)
        def __init__(self, lmap):
            self.grid_feat = np.asarray(lmap.embeddings)
            self.grid_pos = lmap.grid_index.astype(np.int32) + [500, 500, 0]
            self.map_config = {"pose_info": {"pose_type": "mobile_base"}}

    quash = Quash(
        TableEncoder(table=TABLE),
        classifier=registry.create("classifiers", "contrast"),
        cache=False,
    )
    vlmap = VLMap(voxel_map())
    result = quash.query(vlmap, "chair")
    lmap = quash.read_map(vlmap)
    assert lmap.n == len(vlmap.grid_feat) and result.n_matched
    text = queryset_markdown(lmap, result, 0)
    assert "live VLMap object (vlmaps-live)" in text and "memory" not in text
