"""A frame saved with height and width swapped got its landscape image squeezed into a
portrait feature map with nothing said: colours and per-image masks did not line up
with the images. The adapter now warns, naming the images and the fix."""

from __future__ import annotations

import logging

import numpy as np
from _cf_writers import save_feat_pt, save_png

from quash_plugins.core import registry


def _read(folder, caplog):
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="quash_plugins"):
        lmap = registry.create("adapters", "image-features").read(folder)
    return lmap, [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]


def test_images_turned_against_their_frames_are_warned_about(tmp_path, caplog):
    rng = np.random.default_rng(0)
    feat = rng.normal(size=(6, 8, 16)).astype(np.float16)  # (H, W, D): landscape
    images = [rng.integers(0, 255, size=(12, 16, 3), dtype=np.uint8) for _ in range(2)]
    good, turned = tmp_path / "good", tmp_path / "turned"
    for i, rgb in enumerate(images):
        save_feat_pt(good, f"frame{i}", feat)
        save_feat_pt(turned, f"frame{i}", feat.transpose(1, 0, 2))  # saved (W, H, D)
        save_png(good / f"frame{i}.png", rgb)
        save_png(turned / f"frame{i}.png", rgb)

    lmap, warned = _read(good, caplog)
    assert lmap.colors is not None and not warned

    lmap, warned = _read(turned, caplog)
    assert lmap.frames[0].height == 8 and lmap.frames[0].width == 6  # read as given
    assert lmap.colors is not None  # still resized, as before: only now it is said
    assert len(warned) == 1
    said = warned[0]
    assert "2 of 2 RGB images are turned" in said
    assert "frame0.png 16 x 12 for features 6 x 8" in said
    assert "(H, W, D)" in said and "permute(1, 2, 0)" in said
