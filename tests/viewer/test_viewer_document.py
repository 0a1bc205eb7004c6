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
