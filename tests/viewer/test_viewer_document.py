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
    assert f"· {len(on.instances)} instances ·" in queryset_markdown(lmap, on, 0)
