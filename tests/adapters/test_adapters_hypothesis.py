"""Property-based round trips over shapes and dtypes: npz, conceptfusion, image-features."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
from _cf_writers import save_feat_pt, save_pointclouds
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from quash_plugins.adapters import masks_per_frame, read_map
from quash_plugins.adapters._convert import write_npz_streaming

SETTINGS = settings(
    max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
FLOATS = st.sampled_from([np.float16, np.float32])


def _emb(rng, n, d, dtype, zero_rows):
    e = (rng.normal(size=(n, d)) * rng.uniform(0.1, 10.0, size=(n, 1))).astype(dtype)
    e[: min(zero_rows, n)] = 0
    return e


@SETTINGS
@given(
    n=st.integers(1, 40),
    d=st.integers(1, 12),
    dtype=FLOATS,
    zeros=st.integers(0, 3),
    seed=st.integers(0, 2**16),
)
def test_npz_round_trip(n, d, dtype, zeros, seed):
    rng = np.random.default_rng(seed)
    emb = _emb(rng, n, d, dtype, zeros)
    pos = rng.uniform(-5, 5, size=(n, 3)).astype(np.float32)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "m.npz"
        np.savez(path, embeddings=emb, positions=pos)
        lmap = read_map(path)
        assert lmap.dtype == dtype and lmap.n == n
        out = write_npz_streaming(lmap, Path(tmp) / "copy.npz", chunk_rows=7)
        back = read_map(out)
        np.testing.assert_array_equal(np.asarray(back.embeddings), emb)
        np.testing.assert_array_equal(back.positions, pos)


@SETTINGS
@given(
    n=st.integers(1, 40),
    d=st.integers(1, 12),
    dtype=FLOATS,
    zeros=st.integers(0, 3),
    seed=st.integers(0, 2**16),
    colors=st.booleans(),
)
def test_conceptfusion_round_trip(n, d, dtype, zeros, seed, colors):
    rng = np.random.default_rng(seed)
    arrays = {
        "pc_points": rng.uniform(-5, 5, size=(n, 3)).astype(np.float32),
        "pc_embeddings": _emb(rng, n, d, dtype, zeros),
    }
    if colors:
        arrays["pc_colors"] = rng.uniform(0, 255, size=(n, 3)).astype(np.float32)
    with tempfile.TemporaryDirectory() as tmp:
        save_pointclouds(Path(tmp), **arrays)
        lmap = read_map(tmp)
        assert lmap.source["adapter"] == "conceptfusion"
        assert (lmap.n, lmap.dim, lmap.dtype) == (n, d, np.dtype(dtype))
        np.testing.assert_array_equal(lmap.positions, arrays["pc_points"])
        if colors:
            np.testing.assert_array_equal(
                lmap.colors, np.rint(arrays["pc_colors"]).astype(np.uint8)
            )
        raw = arrays["pc_embeddings"].astype(np.float32)
        got = np.concatenate([b for _, _, b in lmap.iter_chunks(5)])
        norms = np.linalg.norm(raw, axis=1, keepdims=True)
        expected = np.divide(raw, norms, out=np.zeros_like(raw), where=norms > 0)
        np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-6)


@st.composite
def frame_sets(draw):
    d = draw(st.integers(1, 8))
    count = draw(st.integers(1, 4))
    frames = []
    for _ in range(count):
        frames.append(
            (
                draw(st.integers(1, 5)),
                draw(st.integers(1, 5)),
                draw(st.sampled_from(["hwd-f16", "1dhw-f32", "npy-f32"])),
            )
        )
    return d, frames


@SETTINGS
@given(spec=frame_sets(), seed=st.integers(0, 2**16))
def test_image_features_round_trip(spec, seed):
    d, frames = spec
    rng = np.random.default_rng(seed)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        per_frame = []
        for i, (h, w, kind) in enumerate(frames):
            rows = rng.normal(size=(h, w, d)).astype(np.float32)
            stem = f"frame{i:03d}"
            if kind == "hwd-f16":
                rows = rows.astype(np.float16)
                save_feat_pt(folder, stem, rows)
            elif kind == "1dhw-f32":
                save_feat_pt(folder, stem, rows.transpose(2, 0, 1)[None])
            else:
                np.save(folder / f"{stem}.npy", rows)
            per_frame.append(rows.reshape(-1, d))
        lmap = read_map(folder, "image-features")
        expected = np.concatenate([p.astype(np.float32) for p in per_frame])
        all_f16 = all(k == "hwd-f16" for _, _, k in frames)
        assert lmap.dtype == (np.float16 if all_f16 else np.float32)
        assert [(f.height, f.width) for f in lmap.frames] == [(h, w) for h, w, _ in frames]
        np.testing.assert_array_equal(np.asarray(lmap.embeddings, dtype=np.float32), expected)
        # A random mask splits back into per-frame masks, frame by frame.
        mask = rng.random(lmap.n) < 0.5
        masks = masks_per_frame(lmap, mask)
        rebuilt = np.concatenate([masks[f.frame_id].ravel() for f in lmap.frames])
        np.testing.assert_array_equal(rebuilt, mask)
