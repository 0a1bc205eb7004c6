"""Frames of a feature folder with no RGB image are named, with the folders searched.

The warning said only "N of M frames have no RGB image; they are shown grey": which
frames, and where their images were looked for, was left to guess.
"""

from __future__ import annotations

import logging

import numpy as np
from _cf_writers import save_feat_pt, save_png

from quash_plugins.adapters import read_map


def test_frames_without_an_image_are_named_with_the_folders_searched(tmp_path, caplog):
    feat = tmp_path / "saved-feat"
    stems = [f"frame{i:06d}" for i in range(6)]
    for stem in stems:
        save_feat_pt(feat, stem, np.ones((4, 6, 8), np.float16))
    rgb = tmp_path / "rgb"
    save_png(rgb / f"{stems[0]}.png", np.full((4, 6, 3), 200, np.uint8))
    save_png(rgb / f"{stems[3]}.jpg", np.full((4, 6, 3), 200, np.uint8))
    with caplog.at_level(logging.WARNING, logger="quash_plugins.adapters"):
        lmap = read_map(feat)
    # frames with an image have its colour, the others are grey
    colors = lmap.colors.reshape(6, -1, 3)
    assert (colors[[0, 3]] == 200).all() and (colors[[1, 2, 4, 5]] == 128).all()
    [record] = [r for r in caplog.records if "have no RGB image" in r.getMessage()]
    msg = record.getMessage()
    assert "4 of 6 frames have no RGB image" in msg, msg
    assert "(frame000001, frame000002, frame000004, ...)" in msg, msg  # the first three
    assert "frame000005" not in msg, msg
    assert "frame000001.png, .jpg" in msg, msg
    assert f"in {feat}, {rgb};" in msg and "-o images=DIR" in msg, msg
