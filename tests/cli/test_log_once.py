"""quash eval with several configs shows each distinct log line once: each config
resolving the same query logged it word for word (3 configs, 3 copies of each line)."""

from __future__ import annotations

import json

import numpy as np
from _eval_table import vec

from quash_plugins import LatentMap
from quash_plugins.adapters import write_npz_map
from quash_plugins.cli.main import main

TAX = {"bed": ["bunk bed", "cot"], "sofa": ["futon", "settee"]}


def test_eval_logs_a_query_resolution_once_for_several_configs(tmp_path, capsys):
    rows = [vec("bed")] * 8 + [vec("sofa")] * 8
    grid = [(x + 10 * b, y, z) for b in (0, 1) for x in (0, 1) for y in (0, 1) for z in (0, 1)]
    write_npz_map(
        LatentMap(
            np.asarray(rows, np.float32),
            kind="voxels",
            grid_index=np.asarray(grid),
            voxel_size=0.1,
            labels=np.repeat([0, 1], 8),
            label_names=["bed", "sofa"],
        ),
        tmp_path / "map.npz",
    )
    names = sorted({n for k, v in TAX.items() for n in (k, *v)} | {"other", "somewhere to nap"})
    np.savez(
        tmp_path / "text.npz",
        texts=np.asarray(names),
        embeddings=np.asarray([vec(n) for n in names], np.float32),
    )
    (tmp_path / "tax.yaml").write_text(json.dumps(TAX))
    for name in ("one", "two"):
        (tmp_path / f"{name}.yaml").write_text(
            f"name: {name}\nencoder: {{name: table, file: text.npz}}\n"
            "heuristic: {name: label-list, file: tax.yaml}\nnegatives: [other]\n"
            "classifier: label-argmax\ninstances: false\ncache: false\n"
        )
    args = ["eval", str(tmp_path / "map.npz"), "-c", str(tmp_path / "one.yaml")]
    args += ["-c", str(tmp_path / "two.yaml"), "--queries", "somewhere to nap=bed"]
    assert main(args) == 0
    err = capsys.readouterr().err
    said = [ln for ln in err.splitlines() if "'somewhere to nap'" in ln]
    assert said and len(said) == len(set(said)), err  # each line once, not once per config
