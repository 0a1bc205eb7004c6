"""OpenScene inputs of a near-miss layout: each error names what was found and the fix.

Points saved as xyz + rgb ``(N, 6)`` or transposed ``(3, N)``, and so on: the refusal
named the file, the field and the shape, but not how to save the points right.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from _openscene_writers import small_scannet_scene

from quash_plugins.adapters import read_map
from quash_plugins.core.errors import MapFormatError


def _scene(root: Path, visible=None):
    return small_scannet_scene(root, seed=7, visible=visible)[:3]


@pytest.mark.parametrize(
    ("layout", "shape", "fix"),
    [("xyzrgb", (40, 6), "arr[:, :3]"), ("transposed", (3, 40), "arr.T")],
)
def test_points_npy_with_rgb_columns_or_transposed_say_how_to_save_them(
    tmp_path, layout, shape, fix
):
    _, pt, coords = _scene(tmp_path)
    if layout == "xyzrgb":
        arr = np.hstack([coords, np.full((40, 3), 128.0)])
    else:
        arr = coords.T
    xyz = tmp_path / "xyz.npy"
    np.save(xyz, arr.astype(np.float32))
    with pytest.raises(MapFormatError) as refused:
        read_map(pt, "openscene", points=str(xyz))
    msg = str(refused.value)
    assert str(xyz) in msg and "'coords'" in msg and str(shape) in msg, msg
    assert f"np.save('{xyz}', {fix})" in msg, msg
    # the fix the message gives reads the map
    np.save(xyz, arr[:, :3] if layout == "xyzrgb" else arr.T)
    lmap = read_map(pt, "openscene", points=str(xyz))
    np.testing.assert_allclose(lmap.positions, coords.astype(np.float32))


def test_mask_full_of_point_indices_says_how_to_build_the_bool_mask(tmp_path):
    """OpenScene's save_fused_feature writes mask_full as a bool mask over all points;
    a .pt holding the indices of the featured points instead was refused with only
    "field 'mask_full' must be bool; got int64"."""
    import torch

    pth, pt, _ = _scene(tmp_path, visible=np.arange(3, 40, 2))
    saved = torch.load(pt, weights_only=True)
    idx = torch.nonzero(saved["mask_full"])[:, 0]
    torch.save({"feat": saved["feat"], "mask_full": idx}, pt)
    with pytest.raises(MapFormatError) as refused:
        read_map(pt, "openscene", points=str(pth))
    msg = str(refused.value)
    assert str(pt) in msg and "'mask_full' must be bool" in msg and "int64" in msg, msg
    assert "indices" in msg and "m = np.zeros(n_points, bool); m[idx] = True" in msg, msg
    assert "feat[np.argsort(idx)]" in msg, msg
    # the fix the message gives reads the map
    m = np.zeros(40, bool)
    m[idx.numpy()] = True
    torch.save({"feat": saved["feat"], "mask_full": torch.from_numpy(m)}, pt)
    lmap = read_map(pt, "openscene", points=str(pth), all_points=False)
    assert lmap.n == 19 and lmap.source["featured_points"] == 19


def test_too_few_label_names_warning_names_the_label_name_file(tmp_path, caplog):
    """The warning 'label ids reach X but only Y label names were given' did not say
    which file of names was short, nor where the label ids came from."""
    pth, pt, _ = _scene(tmp_path)  # ScanNet labels 0, 1, 2
    names = tmp_path / "names.txt"
    names.write_text("wall\nfloor\n")
    with caplog.at_level("WARNING"):
        lmap = read_map(pt, "openscene", points=str(pth), label_names=str(names))
    assert lmap.label_names == ["wall", "floor", "label_2"]
    [record] = [r for r in caplog.records if "label names were given" in r.getMessage()]
    msg = record.getMessage()
    assert f"in {names}; add the missing names to that file" in msg, msg
    assert f"label ids in {pth} reach 2" in msg and "ids 2 to 2" in msg, msg
