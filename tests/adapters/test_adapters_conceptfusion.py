"""ConceptFusion (gradslam pointclouds/) adapter: rows, colours, laziness, queries."""

from __future__ import annotations

import logging
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from _cf_writers import cf_arrays, contrast_config, save_pointclouds, text_table, tree_hash

from quash_plugins import Quash
from quash_plugins.adapters import detect_adapter, read_map
from quash_plugins.cli.main import main
from quash_plugins.core import registry
from quash_plugins.core.errors import MapFormatError
from quash_plugins.core.h5rows import H5Rows


@pytest.fixture
def cf_map(tmp_path):
    arrays = cf_arrays(n=90, d=16)
    save_pointclouds(tmp_path / "saved-map", **arrays)
    return tmp_path / "saved-map", arrays


@pytest.mark.parametrize("which", ["parent", "pointclouds", "file"])
def test_reads_directory_or_parent(cf_map, which):
    root, arrays = cf_map
    source = {
        "parent": root,
        "pointclouds": root / "pointclouds",
        "file": root / "pointclouds" / "pc_points.h5",
    }[which]
    lmap = registry.create("adapters", "conceptfusion").read(source)
    assert lmap.n == 90 and lmap.dim == 16 and lmap.kind == "points"
    np.testing.assert_array_equal(lmap.positions, arrays["pc_points"])
    expected = np.clip(np.rint(arrays["pc_colors"]), 0, 255).astype(np.uint8)
    np.testing.assert_array_equal(lmap.colors, expected)
    assert detect_adapter(source) == "conceptfusion"


def test_float16_kept_lazily_and_rows_normalised(cf_map):
    root, arrays = cf_map
    lmap = read_map(root)
    assert isinstance(lmap.embeddings, H5Rows)  # on disk, read block by block
    assert lmap.embeddings.dtype == np.float16
    assert lmap.normalize is True
    raw = arrays["pc_embeddings"].astype(np.float32)
    norms = np.linalg.norm(raw, axis=1)
    for start, stop, block in lmap.iter_chunks(17):
        assert block.dtype == np.float32
        for i, row in zip(range(start, stop), block):
            if norms[i] == 0:
                assert not row.any()
            else:
                np.testing.assert_allclose(row, raw[i] / norms[i], rtol=1e-5, atol=1e-6)


def test_float32_embeddings_and_only_required_files(tmp_path):
    arrays = cf_arrays(n=30, d=8, dtype=np.float32)
    save_pointclouds(tmp_path, pc_points=arrays["pc_points"], pc_embeddings=arrays["pc_embeddings"])
    lmap = read_map(tmp_path)
    assert lmap.embeddings.dtype == np.float32 and lmap.colors is None
    np.testing.assert_array_equal(np.asarray(lmap.embeddings[:]), arrays["pc_embeddings"])


@pytest.mark.parametrize("field", ["pc_points", "pc_embeddings"])
def test_a_padded_batch_of_one_cloud_says_to_save_its_first_entry(tmp_path, field):
    arrays = cf_arrays()
    arrays[field] = arrays[field][None]  # gradslam's padded (1, N, ...) layout
    save_pointclouds(tmp_path, pc_points=arrays["pc_points"], pc_embeddings=arrays["pc_embeddings"])
    name = "points" if field == "pc_points" else "embeddings"
    with pytest.raises(MapFormatError, match=rf"{field}.*batch of one cloud.*save {name}\[0\]"):
        read_map(tmp_path, "conceptfusion")


def test_zero_rows_never_match_end_to_end(tmp_path):
    table, vecs = text_table(tmp_path, 16)
    chair_rows = [1, 2, 4, 7, 8]
    arrays = cf_arrays(n=40, d=16, vecs=vecs, chair_rows=chair_rows, zero_every=4)
    save_pointclouds(tmp_path / "m", **arrays)
    emb = arrays["pc_embeddings"].astype(np.float32)
    # Independent expectation: closer to chair than to every negative, and non-zero.
    unit = emb / np.maximum(np.linalg.norm(emb, axis=1, keepdims=True), 1e-12)
    score = unit @ vecs["chair"] - np.max(
        unit @ np.stack([vecs[w] for w in ("other", "background", "nothing")]).T, axis=1
    )
    expected = (score > 0) & (np.abs(emb).sum(axis=1) > 0)
    assert expected.sum() == 3  # chair rows 4 and 8 are zeroed: only 1, 2, 7 remain
    quash = Quash.from_config(contrast_config(tmp_path, table), cache=False)
    result = quash.query(tmp_path / "m", "chair")
    np.testing.assert_array_equal(result.mask, expected)
    assert not result.mask[::4].any()


def test_cli_query_auto(tmp_path):
    table, vecs = text_table(tmp_path, 16)
    arrays = cf_arrays(n=40, d=16, vecs=vecs, chair_rows=[1, 2, 3])
    save_pointclouds(tmp_path / "m", **arrays)
    before = tree_hash(tmp_path / "m")
    out = tmp_path / "r.npz"
    cfg = contrast_config(tmp_path, table)
    rc = main(
        [
            "-q",
            "query",
            str(tmp_path / "m"),
            "chair",
            "-c",
            str(cfg),
            "--adapter",
            "auto",
            "--out",
            str(out),
        ]
    )
    assert rc == 0
    with np.load(out) as z:
        assert z["masks"].shape == (1, 40)
        assert z["masks"][0, [1, 2, 3]].all() and z["masks"][0].sum() == 3
    assert tree_hash(tmp_path / "m") == before


def test_color_range_option(tmp_path, caplog):
    arrays = cf_arrays(n=10, d=4)
    arrays["pc_colors"] = np.full((10, 3), 0.5, dtype=np.float32)
    save_pointclouds(tmp_path, **arrays)
    lmap = registry.create("adapters", "conceptfusion", color_range="0-1").read(tmp_path)
    assert (lmap.colors == 128).all()
    # Default 0-255: a dark colour stays dark (no silent 0-1 guess), but it is said.
    with caplog.at_level(logging.WARNING):
        assert (read_map(tmp_path).colors <= 1).all()
    assert "pc_colors" in caplog.text and "color_range '0-1' or 'auto'" in caplog.text


def test_color_range_0_1_refused_for_0_255_colours(tmp_path):
    """0-255 colours read as 0-1 would all be white: refused, naming the file and option."""

    save_pointclouds(tmp_path, **cf_arrays(n=10, d=4))
    with pytest.raises(MapFormatError) as info:
        registry.create("adapters", "conceptfusion", color_range="0-1").read(tmp_path)
    msg = str(info.value)
    assert "pc_colors.h5" in msg and "'colors'" in msg and "color_range '0-255' or 'auto'" in msg
    assert read_map(tmp_path, "conceptfusion", color_range="auto").colors.max() > 200


def test_docs_conceptfusion_yaml_is_the_default_config_with_its_encoder():
    """adapters.md's conceptfusion.yaml, which its commands name, is what it says."""
    import re
    from pathlib import Path

    import yaml

    from quash_plugins import QuashConfig

    doc = (Path(__file__).resolve().parents[2] / "docs" / "adapters.md").read_text()
    section = doc[doc.index("## conceptfusion") : doc.index("## image-features")]
    (block,) = re.findall(r"```yaml\n(.*?)```", section, flags=re.S)
    cfg = QuashConfig.from_dict(yaml.safe_load(block))
    assert cfg.encoder.name == "open-clip" and cfg.encoder.params == {"preset": "conceptfusion"}
    default = QuashConfig.default()
    assert replace(cfg, name=default.name, encoder=default.encoder) == default


def test_a_folder_that_also_holds_another_map_is_refused_with_the_choices(cf_map, capsys):
    """``saved-map/`` with ``pointclouds/`` and a portable ``other.npz`` map beside it:
    ``auto`` does not pick one silently; the error names the folder, both candidates and
    how to choose, and each choice reads what it names."""
    from quash_plugins.adapters import write_npz_map
    from quash_plugins.core.types import LatentMap

    root, arrays = cf_map
    emb = np.random.default_rng(1).normal(size=(7, 16)).astype(np.float32)
    other = write_npz_map(LatentMap(emb, kind="points"), root / "other.npz")
    with pytest.raises(MapFormatError) as exc:
        read_map(root)
    msg = str(exc.value)
    assert str(root) in msg and f"{other} (npz)" in msg
    assert "--adapter conceptfusion" in msg and "pass the file itself" in msg
    assert read_map(root, adapter="conceptfusion").n == len(arrays["pc_points"])
    assert read_map(other).n == 7
    assert detect_adapter(root / "pointclouds") == "conceptfusion"  # the map's own folder
    code = main(["query", str(root), "chair", "-c", "demo:quash-labels"])
    assert code != 0 and "--adapter conceptfusion" in capsys.readouterr().err


def test_an_npz_that_is_no_map_beside_pointclouds_changes_nothing(cf_map):
    """An unrelated ``.npz`` (a results file, any archive without ``embeddings``) is no
    second map: the folder is still read as ConceptFusion."""
    root, arrays = cf_map
    np.savez(root / "poses.npz", poses=np.eye(4)[None].repeat(3, axis=0))
    assert detect_adapter(root) == "conceptfusion"
    assert read_map(root).n == len(arrays["pc_points"])


def test_a_map_file_of_a_suffixless_format_beside_pointclouds_is_refused(cf_map, tmp_path):
    """The folder check saw only formats that declare a suffix (.npz, .zarr, .h5df): an
    OpenScene fused .pt (or a VLMaps grid_lseg_1.npy) in saved-map/ beside pointclouds/
    was silently ignored and the folder read as ConceptFusion. Adapters without suffixes
    are asked too (their sniff reads the content), for files; each choice still works."""
    import shutil

    from quash_plugins.adapters._openscene import OpenSceneAdapter

    root, arrays = cf_map
    example = OpenSceneAdapter().write_example(tmp_path / "os")
    fused = Path(shutil.copy(example, root / "scene0000_00_0.pt"))
    with pytest.raises(MapFormatError) as exc:
        detect_adapter(root)
    msg = str(exc.value)
    assert str(root) in msg and f"{fused} (openscene)" in msg
    assert "--adapter conceptfusion" in msg and "pass the file itself" in msg
    assert read_map(root, adapter="conceptfusion").n == len(arrays["pc_points"])
    fused.unlink()
    grid = root / "grid_lseg_1.npy"
    np.save(grid, np.zeros((6, 6, 4), np.float32))
    with pytest.raises(MapFormatError, match=rf"{grid} \(vlmaps-2d\)"):
        detect_adapter(root)
    grid.unlink()
    np.save(root / "labels.npy", np.zeros(5, np.int64))  # no map: changes nothing
    # files named as no format's maps count not, whatever a loose sniff would say of them
    # (image-features takes any .pt, vlmaps-2d any square float array)
    np.save(root / "features.npy", np.zeros((6, 6, 4), np.float32))
    shutil.copy(example, root / "notes.pt")
    assert detect_adapter(root) == "conceptfusion"


def test_the_finite_scan_shows_progress(tmp_path, caplog, monkeypatch):
    """check_finite: true reads every embedding before the map is returned (a 1 GB map:
    4 s here, a real one several times that) and said nothing; it now reports progress."""
    monkeypatch.setattr("quash_plugins.core.progress.MIN_INTERVAL", 0.0)  # fast here
    monkeypatch.setattr("quash_plugins.core.progress.QUIET", False)
    save_pointclouds(tmp_path / "saved-map", **cf_arrays(n=50, d=8))
    caplog.set_level(logging.INFO, logger="quash_plugins.progress")
    read_map(tmp_path / "saved-map", check_finite=True)
    assert "checking embeddings for NaN/Inf: 50/50 (100%" in caplog.text
