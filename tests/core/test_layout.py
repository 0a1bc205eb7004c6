"""core.layout: the one definition of a map's up axis and frames in files."""

from __future__ import annotations

import numpy as np
import pytest

from quash_plugins.core.errors import MapFormatError
from quash_plugins.core.layout import (
    layout_arrays,
    layout_up,
    map_layout,
    read_frames,
    read_up,
)
from quash_plugins.core.types import FrameInfo, LatentMap


def _pixel_map(up=None):
    frames = [FrameInfo("a", 2, 3, 0, image_path="a.png"), FrameInfo("b", 1, 4, 6)]
    source = {"up": up} if up else {}
    return LatentMap(np.ones((10, 4), np.float32), kind="pixels", frames=frames, source=source)


def test_layout_of_a_pixel_map_as_values_and_arrays():
    layout = map_layout(_pixel_map(up="+y"))
    assert layout == {
        "frame_ids": ["a", "b"],
        "frame_hw": [[2, 3], [1, 4]],
        "frame_offsets": [0, 6],
        "up": "+y",
    }
    arrays = layout_arrays(layout)
    assert arrays["frame_hw"].shape == (2, 2) and arrays["frame_hw"].dtype == np.int64
    assert arrays["frame_offsets"].dtype == np.int64 and arrays["frame_ids"].dtype.kind == "U"
    assert arrays["up"].shape == () and str(arrays["up"]) == "+y"


def test_given_up_axis_wins_and_an_unknown_one_is_not_recorded():
    assert map_layout(_pixel_map(up="+y"), "-x")["up"] == "-x"
    assert "up" not in map_layout(_pixel_map(up="sideways"))
    assert layout_up({"up": "+y"}, "up") is None  # a given value that is no axis
    assert map_layout(LatentMap(np.ones((3, 2), np.float32))) == {}


@pytest.mark.parametrize("as_arrays", [True, False])
def test_read_back_what_was_written(as_arrays):
    lmap = _pixel_map(up="-z")
    layout = map_layout(lmap)
    fields = layout_arrays(layout) if as_arrays else layout
    expected = [FrameInfo(f.frame_id, f.height, f.width, f.offset) for f in lmap.frames]
    assert read_frames(fields, "x") == expected
    assert read_up(fields, "x") == "-z"
    assert read_frames({}, "x") is None and read_up({}, "x") is None


def test_malformed_fields_are_refused_by_name():
    fields = map_layout(_pixel_map())
    with pytest.raises(MapFormatError, match=r"r\.zarr: attributes 'frame_hw' must be \(F, 2\)"):
        read_frames({**fields, "frame_hw": [[2, 3]]}, "r.zarr", what="attribute")
    with pytest.raises(MapFormatError, match="'frame_offsets'"):
        read_frames({**fields, "frame_offsets": ["x", "y"]}, "m.npz")
    with pytest.raises(MapFormatError, match="m.npz: array 'up' is 'y', not an up axis"):
        read_up({"up": np.asarray("y")}, "m.npz")
