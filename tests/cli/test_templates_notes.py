"""``quash eval`` (no ``-c``) and ``quash demo`` on a machine without VLMaps: their VLMaps
peers ask for ``templates: vlmaps-or-default``, so our default prompt templates stand in,
said at INFO; stderr carries no templates warning, and the JSON says which list was used."""

from __future__ import annotations

import json

import numpy as np
import pytest

from quash_plugins import LatentMap
from quash_plugins.adapters import write_npz_map
from quash_plugins.cli.main import main


def vlmaps_lines(err: str) -> list[str]:
    """The log lines about VLMaps' templates (plain ``LEVEL message`` lines off a tty)."""
    return [ln for ln in err.splitlines() if "VLMaps" in ln]


@pytest.mark.slow
def test_eval_without_c_says_the_templates_at_info_not_as_a_warning(no_vlmaps, tmp_path, capsys):
    pytest.importorskip("sentence_transformers")
    from quash_plugins.core.registry import create

    dim = create("encoders", "minilm").dim  # a map in the default config's text space
    rng = np.random.default_rng(0)
    grid = [(x + 4 * b, y, 0) for b in (0, 1) for x in (0, 1, 2) for y in (0, 1, 2)]
    write_npz_map(
        LatentMap(
            rng.standard_normal((len(grid), dim)).astype(np.float32),
            kind="voxels",
            grid_index=np.asarray(grid),
            voxel_size=0.1,
            labels=np.repeat([0, 1], len(grid) // 2),
            label_names=["bed", "sofa"],
        ),
        tmp_path / "map.npz",
    )
    out = tmp_path / "eval.json"
    args = ["eval", str(tmp_path / "map.npz"), "--queries", "bed", "--json", str(out)]
    assert main(args) == 0
    said = vlmaps_lines(capsys.readouterr().err)
    assert said, "the stand-in templates are said at INFO"
    assert all(ln.startswith("INFO") for ln in said), said
    assert any("vlmaps-or-default" in ln for ln in said), said
    rows = {c["name"]: c for c in json.loads(out.read_text())["provenance"]["configs"]}
    assert "no VLMaps installed" in rows["vlmaps-labels"]["templates"]
    assert rows["openscene-labels"]["templates"] is None  # no templates at all


def test_expand_says_which_templates_it_used(no_vlmaps, tiny_world, capsys):
    config = tiny_world["dir"] / "templated.yaml"
    config.write_text(
        tiny_world["config"].read_text()
        + "prompt_templates: {mode: mean, templates: vlmaps-or-default}\n"
    )
    assert main(["expand", "chair", "-c", str(config), "--json"]) == 0
    got = json.loads(capsys.readouterr().out)["provenance"]["prompt_templates"]
    assert got["source"] == "our default list (vlmaps-or-default: no VLMaps installed)"
    assert main(["expand", "chair", "-c", str(config)]) == 0
    printed = " ".join(capsys.readouterr().out.split())  # rich may wrap the line
    assert f"{got['count']} prompt templates from our default list (vlmaps-or-default" in printed
