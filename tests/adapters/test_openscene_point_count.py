"""Features of another scene than their points: the error names the features' own field.

A ``<scene>_openscene_feat_<type>.npy`` (OpenScene's per-point features, one row per
point) has no ``mask_full``, yet a row count that is not the scene's was reported as
"field 'mask_full' has N entries". Each error now names the field the file holds, the
points file in full (it may have been found, not given) and the option that fixes it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from _openscene_writers import preprocess_scannet, small_scannet_scene

from quash_plugins.adapters import read_map
from quash_plugins.core.errors import MapFormatError


def _scene(root: Path):
    pth, pt, _, feat_bank = small_scannet_scene(root, seed=4)
    return pth, pt, feat_bank


def test_per_point_features_of_another_scene_name_their_rows_not_mask_full(tmp_path):
    pth, _, feat_bank = _scene(tmp_path)
    npy = tmp_path / "openseg" / "scene0011_00_openscene_feat_ensemble.npy"
    np.save(npy, feat_bank[:-3].astype(np.float16))  # 37 rows for 40 points
    with pytest.raises(MapFormatError) as refused:
        read_map(npy)
    said = str(refused.value)
    assert "mask_full" not in said
    assert f"{npy}: field 'feat' has 37 rows (one per point)" in said
    assert f"{pth} has 40 points" in said and "points=PATH" in said
    np.save(npy, feat_bank.astype(np.float16))  # the scene's own rows read
    assert read_map(npy).n == 40


def test_fused_features_of_another_scene_name_mask_full_and_the_points_in_full(tmp_path):
    pth, pt, _ = _scene(tmp_path)
    smaller = preprocess_scannet(
        tmp_path / "other" / "scene0011_00_vh_clean_2.pth",
        np.zeros((30, 3)),
        np.zeros((30, 3)),
        np.zeros(30),
    )
    with pytest.raises(MapFormatError) as refused:
        read_map(pt, points=str(smaller))
    said = str(refused.value)
    assert "field 'mask_full' has 40 entries" in said
    assert f"{smaller} has 30 points" in said and "points=PATH" in said
    assert read_map(pt, points=str(pth)).n == 40
