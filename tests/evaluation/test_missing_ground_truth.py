"""quash eval on a map without ground truth says which half is missing and where it
comes from for the map's format."""

from __future__ import annotations

import numpy as np
import pytest

from quash_plugins import Quash
from quash_plugins.adapters import write_npz_map
from quash_plugins.core.errors import QuashError
from quash_plugins.core.types import LatentMap
from quash_plugins.evaluation.report import evaluate, missing_ground_truth

E = np.eye(4, dtype=np.float32)


def test_labels_without_names_in_an_npz_say_the_names_are_missing(tmp_path):
    path = write_npz_map(LatentMap(E, labels=np.array([0, 1, 0, 1])), tmp_path / "m.npz")
    q = Quash.from_config({"encoder": {"name": "table", "table": {"a": [1, 0, 0, 0]}}})
    with pytest.raises(QuashError) as err:
        evaluate(str(path), [q])
    msg = str(err.value)
    assert str(path) in msg and "labels but no label names" in msg
    assert "label_names (L,)" in msg


def test_a_vlmaps_map_names_the_adapter_option_and_the_forks_files():
    with_labels = LatentMap(
        E, labels=np.array([0, 1, 0, 1]), source={"adapter": "vlmaps-2d", "path": "m/map"}
    )
    msg = missing_ground_truth(with_labels)
    assert "'adapter: {name: vlmaps-2d, label_names: names.txt}'" in msg
    assert "-o label_names=names.txt" in msg and "obj2cls_dict.txt" in msg
    bare = LatentMap(E, source={"adapter": "vlmaps", "path": "vlmap/vlmaps.h5df"})
    msg = missing_ground_truth(bare)
    assert "no ground-truth labels" in msg and "Upstream VLMaps writes no ground truth" in msg
    assert "grid_semantic" in msg


def test_an_unlabelled_map_says_how_to_add_ground_truth():
    """A ConceptFusion point cloud has no labels: the message names the NPZ arrays to add."""
    bare = LatentMap(E, source={"adapter": "conceptfusion", "path": "saved-map/pointclouds"})
    msg = missing_ground_truth(bare)
    assert "saved-map/pointclouds" in msg and "no ground-truth labels" in msg
    assert "quash convert MAP map.npz" in msg and "labels (N,)" in msg and "label_names" in msg


def test_a_map_whose_every_item_is_unlabelled_is_refused_not_scored_as_absent(tmp_path):
    """Every label -1: each query was scored as an absence query, and a method that
    matched 107 items got absence 1.000. No item can be scored, so nothing is."""
    path = write_npz_map(
        LatentMap(E, labels=np.full(4, -1), label_names=["bed", "sofa"]), tmp_path / "m.npz"
    )
    q = Quash.from_config({"encoder": {"name": "table", "table": {"bed": [1, 0, 0, 0]}}})
    with pytest.raises(QuashError, match="every item's label is negative") as info:
        evaluate(str(path), [q], queries=["bed"])
    assert "exclude" not in str(info.value)  # excluding fewer labels cannot help (nor bench)
    labelled = write_npz_map(
        LatentMap(E, labels=np.array([0, 0, 1, 1]), label_names=["bed", "wall"]), tmp_path / "w.npz"
    )
    with pytest.raises(
        QuashError,
        match=r"every labelled item has an excluded label \(bed, wall\).*--exclude",
    ):
        evaluate(str(labelled), [q], exclude=["bed", "wall"])


def test_the_mean_always_holds_every_metric():
    """With no present query (absence queries only), 'mean' lacked ap and inv_rank, which
    the docs and --help list: every key is there, null."""
    from quash_plugins.evaluation.metrics import METRICS, RANKING, macro_mean

    assert macro_mean({}) == dict.fromkeys((*METRICS, *RANKING))
    one = {"precision": 1.0, "recall": 0.5, "f1": 2 / 3, "iou": 0.5, "ap": None}
    mean = macro_mean({"chair": one})
    assert set(mean) == {*METRICS, *RANKING} and mean["ap"] is None and mean["inv_rank"] is None


def test_a_map_with_no_items_says_so_not_that_its_items_are_unlabelled(tmp_path):
    """An empty map (0 items) was refused as 'every item's label is negative
    (unlabelled)' with the advice of fewer --exclude labels; it says the map is empty."""
    empty = LatentMap(
        np.zeros((0, 4), np.float32), labels=np.zeros(0, int), label_names=["bed", "sofa"]
    )
    path = write_npz_map(empty, tmp_path / "m.npz")
    q = Quash.from_config({"encoder": {"name": "table", "table": {"bed": [1, 0, 0, 0]}}})
    with pytest.raises(QuashError) as err:
        evaluate(str(path), [q], queries=["bed"])
    msg = str(err.value)
    assert str(path) in msg and "has no items" in msg
    assert "negative" not in msg and "--exclude" not in msg


@pytest.mark.parametrize("names", [["bed", "sofa", "bed"], ["bed", "bed", "sofa"]])
def test_a_label_name_given_twice_in_the_map_is_one_label_whose_items_are_all_truth(
    tmp_path, caplog, names
):
    """label_names ['bed', 'sofa', 'bed']: a query of 'bed' took label 2 as its ground
    truth and scored the items of label 0, beds too, as false positives (F1 0.018 for a
    rule whose F1 was 0.226 on the same map with one name per label). Every label of
    that name is now the query's ground truth, with a warning; the map is not written."""
    labels = np.array([0, 0, 1, 2]) if names[2] == "bed" else np.array([0, 1, 2, 0])
    bed = np.array([n == "bed" for n in names])[labels]  # the items of every 'bed'
    lmap = LatentMap(E, labels=labels.copy(), label_names=names)
    path = write_npz_map(lmap, tmp_path / "m.npz")
    table = {"bed": [1, 0, 0, 0], "sofa": [0, 0, 1, 0], "cot": [1, 0, 0, 0]}
    table |= {"other": [0, 1, 0, 0], "background": [0, 0, 0, 1], "nothing": [0, 0, 0, 1]}
    q = Quash.from_config({"encoder": {"name": "table", "table": table}, "heuristic": "none"})
    for kwargs in ({"queries": ["bed"]}, {"queries": ["cot=bed"]}, {}):
        caplog.clear()
        report = evaluate(str(path), [q], keep_results=True, **kwargs)
        [query] = [k for k in report.queries if k in ("bed", "cot")]
        m = report.configs[0]["per_query"][query]
        assert m["label"] == "bed" and m["n_true"] == int(bed.sum()) == 3, m
        [result] = [r for r in next(iter(report.results.values())) if r.query == query]
        expect = np.count_nonzero(result.mask & bed)
        assert m["tp"] == expect and m["fp"] == np.count_nonzero(result.mask & ~bed)
        assert "'label_names' gives 'bed' to more than one label" in caplog.text
    # the names the map holds are each queried once, and the map's labels are its own
    assert sorted(evaluate(lmap, [q]).queries) == ["bed", "sofa"]
    assert lmap.labels.tolist() == labels.tolist()
