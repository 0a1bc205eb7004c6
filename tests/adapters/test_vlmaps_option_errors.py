"""The VLMaps adapters' gs/cs errors name what was given (option or the map's own value),
the map and what to give instead; the last paths that did not (see _vlmaps_options)."""

from __future__ import annotations

import logging
from types import SimpleNamespace

import numpy as np
import pytest
from _vlmaps_writers import mobile_map, write_vlmaps_2d, write_vlmaps_h5df

from quash_plugins.core import registry
from quash_plugins.core.errors import MapFormatError

D = 8
CS_FIX = (
    "Give the map config's cell_size, in metres (VLMaps' default: 0.05), or drop the cs option."
)
CAMERA = {"pcd_min": [0.0, 0.0, 0.0], "pcd_max": [1.0, 1.0, 1.0], "cs": 0.05}
BAD_CS = (
    (0, "positive"),
    (-0.05, "positive"),
    ("nan", "finite, positive"),
    ("inf", "finite, positive"),
)


def test_a_2d_grid_cs_option_that_is_no_positive_number_names_the_option_and_the_fix(tmp_path):
    """vlmaps-2d read cs with float(): cs='abc' raised Python's ValueError, and cs=0 said
    'cell size cs must be positive; got 0.0' naming neither the option nor the fix."""
    folder, _ = write_vlmaps_2d(tmp_path / "scene", gs=10, d=D)
    adapter = registry.create("adapters", "vlmaps-2d")
    where = str(folder / "grid_lseg_1.npy")
    for bad, what in (("abc", "is not a number"), (True, "is not a number")) + tuple(
        (b, f"must be a {size} number") for b, size in BAD_CS
    ):
        with pytest.raises(MapFormatError) as info:
            adapter.read(folder, cs=bad)
        assert str(info.value) == f"{where}: option cs={bad!r} {what}. {CS_FIX}"
    assert adapter.read(folder, cs="0.1").voxel_size == pytest.approx(0.1)


def test_a_camera_base_file_without_cs_checks_the_cs_option_like_any_other(tmp_path):
    """A camera-base file that stores no cs takes it from the option, which was checked
    by its own rule: 'cell size cs must be a positive number; got 'abc'', naming neither
    the option nor what to give. It now says so as every other cs option does, with the
    fix for such a map (the option cannot be dropped there)."""
    arrays = mobile_map(n=5, d=D)
    path = write_vlmaps_h5df(tmp_path / "cam.h5df", arrays, camera=CAMERA, drop=("cs",))
    adapter = registry.create("adapters", "vlmaps")
    fix = (
        "Give the map config's cell_size, in metres (VLMaps' default: 0.05): this "
        "camera-base map stores no cs of its own."
    )
    for bad, what in (("abc", "is not a number"),) + tuple(
        (b, f"must be a {size} number") for b, size in BAD_CS
    ):
        with pytest.raises(MapFormatError) as info:
            adapter.read(path, cs=bad)
        assert str(info.value) == f"{path}: option cs={bad!r} {what}. {fix}"
    with pytest.raises(MapFormatError, match="lacks field 'cs'; pass the map config's"):
        adapter.read(path)
    assert adapter.read(path, cs="0.1").source["cs"] == pytest.approx(0.1)
    # a cs the file stores itself is the file's fault, named as its field
    stored = write_vlmaps_h5df(tmp_path / "zero.h5df", arrays, camera={**CAMERA, "cs": 0.0})
    with pytest.raises(MapFormatError) as info:
        adapter.read(stored)
    assert str(info.value) == (
        f"{stored}: field 'cs' (the cell size) must be a positive number; got 0."
    )


def _live(gs):
    arrays = mobile_map(n=5, d=D)
    live = SimpleNamespace(grid_feat=arrays["grid_feat"], grid_pos=arrays["grid_pos"], gs=gs)
    live.map_config = {"pose_info": {"pose_type": "mobile_base"}}
    return live


def test_a_live_maps_own_gs_is_named_as_its_attribute_not_as_an_option():
    """vlmap.gs (its map config's grid_size) went through the gs option's check, so
    vlmap.gs=0 said 'option gs=0 must be ...' though no option was given, vlmap.gs='x'
    raised int()'s ValueError and vlmap.gs=12.5 was cut to 12."""
    adapter = registry.create("adapters", "vlmaps-live")
    where = "live SimpleNamespace object"
    fix = (
        "Set grid_size in its map config, in cells per side (VLMaps' default: 1000), or "
        "pass the gs option."
    )
    for bad, what in (
        (0, "must be a positive whole number"),
        (-4, "must be a positive whole number"),
        ("x", "is not a whole number"),
        (12.5, "is not a whole number"),
    ):
        with pytest.raises(MapFormatError) as info:
            adapter.read(_live(bad))
        assert str(info.value) == (
            f"{where}: the VLMap object's gs attribute (vlmap.gs={bad!r}, its map config's "
            f"grid_size) {what}. {fix}"
        )
        assert "option" not in str(info.value).split(".")[0]
        # the fix it names works: a gs option replaces the attribute
        assert adapter.read(_live(bad), gs=60).source["gs"] == 60
    lmap = adapter.read(_live(60))
    assert (lmap.source["gs"], lmap.source["gs_from"]) == (60, "attribute")


def test_a_live_maps_own_gs_that_is_no_number_beside_occupied_ids_is_a_warning(caplog):
    """With occupied_ids the grid size is read from it and vlmap.gs is only compared
    (int(vlmap.gs) raised ValueError on 'x'): a vlmap.gs that is no number disagrees."""
    live = _live("x")
    arrays = mobile_map(n=5, d=D)
    live.occupied_ids = -np.ones((arrays["gs"], arrays["gs"], 2), dtype=np.int32)
    adapter = registry.create("adapters", "vlmaps-live")
    with caplog.at_level(logging.WARNING, logger="quash_plugins"):
        lmap = adapter.read(live)
    assert lmap.source["gs"] == arrays["gs"]
    assert "vlmap.gs = x (the map config's grid_size) disagrees with occupied_ids" in caplog.text


def test_a_live_maps_own_cs_is_named_as_its_attribute_not_as_an_option():
    """vlmap.cs (its map config's cell_size) that is no positive number said 'cell size cs
    must be a positive number; got 0.0', naming neither the attribute nor the fix, and
    vlmap.cs='abc' raised float()'s ValueError."""
    adapter = registry.create("adapters", "vlmaps-live")
    where = "live SimpleNamespace object"
    fix = (
        "Set cell_size in its map config, in metres (VLMaps' default: 0.05), or pass the cs option."
    )
    for bad, what in (
        ("abc", "is not a number"),
        (True, "is not a number"),
        (0, "must be a positive number"),
        (-0.05, "must be a positive number"),
        (float("nan"), "must be a finite, positive number"),
    ):
        live = _live(60)
        live.cs = bad
        with pytest.raises(MapFormatError) as info:
            adapter.read(live)
        assert str(info.value) == (
            f"{where}: the VLMap object's cs attribute (vlmap.cs={bad!r}, its map config's "
            f"cell_size) {what}. {fix}"
        )
        # the fix it names works: a cs option replaces the attribute
        assert adapter.read(live, cs=0.1).source["cs"] == pytest.approx(0.1)
    live = _live(60)
    live.cs = np.array([0.0])  # as VLMap.load_map reads it: named by its value
    with pytest.raises(MapFormatError, match=r"\(vlmap\.cs=0\.0, its map config's cell_size\)"):
        adapter.read(live)
    live.cs = np.array([0.1])
    assert adapter.read(live).source["cs"] == pytest.approx(0.1)
