"""The docs' code runs, and the generated config reference is current.

Every ```python block of the user guides runs as written, in a folder holding stand-ins
for the files it names (``quash.yaml``, ``map.npz``, ``scene.npz``, a VLMaps
``vlmap/vlmaps.h5df``...): small labelled maps and configs with a ``table`` encoder,
since the guides' own configs need model weights. A block that cannot run here (it
needs weights, the network or a cluster) says so in its first lines, visibly, with a
comment ``# Not run by the docs test: <reason>``; it is skipped with that reason.
"""

from __future__ import annotations

import contextlib
import io
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from quash_plugins.core import registry
from quash_plugins.core.config import config_reference

DOCS = Path(__file__).resolve().parents[2] / "docs"
GUIDES = ("quickstart.md", "scale.md", "rerun.md", "evaluation.md", "encoders.md", "config.md")
SKIP = re.compile(r"^# Not run by the docs test: (?P<reason>.+)$", re.M)
WORDS = ["chair", "sofa", "table", "piano", "other", "background", "nothing"]


def _python_blocks(md: str) -> list[tuple[int, str]]:
    """``(line, code)`` of every block fenced as exactly ```python."""
    return [
        (md[: m.start()].count("\n") + 2, m.group(1))
        for m in re.finditer(r"^```python\n(.*?)^```", md, flags=re.S | re.M)
    ]


def _skip_reason(code: str) -> str | None:
    """The reason a block gives for not running, from its leading comment lines."""
    head = []
    for line in code.splitlines():
        if not line.startswith("#"):
            break
        head.append(line)
    m = SKIP.search("\n".join(head))
    return m.group("reason").strip() if m else None


def _cases() -> list:
    cases = []
    for doc in GUIDES:
        for line, code in _python_blocks((DOCS / doc).read_text(encoding="utf-8")):
            reason = _skip_reason(code)
            marks = [pytest.mark.skip(reason=f"docs/{doc}:{line}: {reason}")] if reason else []
            cases.append(pytest.param(doc, line, code, id=f"{doc}:{line}", marks=marks))
    return cases


CASES = _cases()


def test_every_guide_has_python_blocks_and_most_run():
    docs = {c.values[0] for c in CASES}
    assert docs == set(GUIDES)
    running = [c for c in CASES if not c.marks]
    assert len(running) >= 5, "the guides' Python examples must run, not be skipped"


def test_skip_markers_are_found_only_in_the_leading_comments():
    assert _skip_reason("# Not run by the docs test: needs a GPU.\nimport x\n") == "needs a GPU."
    assert _skip_reason("# pip install x\n# Not run by the docs test: cluster\nx = 1\n") == (
        "cluster"
    )
    assert _skip_reason("x = 1\n# Not run by the docs test: later\n") is None


def _stand_ins(folder: Path) -> None:
    """The user files the guides name, small and offline."""
    from _vlmaps_writers import write_vlmaps_h5df

    from quash_plugins.adapters import write_npz_map
    from quash_plugins.core.types import LatentMap

    rng = np.random.default_rng(0)
    d = 16
    T = rng.normal(size=(len(WORDS), d)).astype(np.float32)
    T /= np.linalg.norm(T, axis=1, keepdims=True)
    np.savez(folder / "text.npz", texts=np.asarray(WORDS), embeddings=T)
    enc = {"name": "table", "file": "text.npz"}
    for name, classifier in (("quash", "nearest-sample"), ("vlmaps", "contrast")):
        cfg = {"name": name, "encoder": enc, "heuristic": "none", "classifier": classifier}
        (folder / f"{name}.yaml").write_text(yaml.safe_dump(cfg), encoding="utf-8")
    # Shipped configs named in the guides (-c demo:quash-labels): a file of that name in
    # the current folder wins over the shipped one, so these stand in for them here.
    # tests/cli/test_doc_commands.py runs the quickstart with the real ones.
    for name in ("demo:quash-taxonomy", "demo:quash-labels", "demo:vlmaps"):
        cfg = {"name": name.split(":")[1], "encoder": enc, "classifier": "nearest-sample"}
        (folder / name).write_text(yaml.safe_dump(cfg), encoding="utf-8")
    labels = rng.integers(0, 3, size=400)
    E = T[labels] + 0.3 * rng.normal(size=(400, d))
    positions = rng.uniform(0, 4, size=(400, 3)).astype(np.float32)
    lmap = LatentMap(
        E.astype(np.float32), positions=positions, labels=labels, label_names=WORDS[:3]
    )
    write_npz_map(lmap, folder / "map.npz")
    write_npz_map(lmap, folder / "scene.npz")
    gs, vh = 40, 10
    cells = rng.choice(gs * gs * vh, size=400, replace=False)
    grid_pos = np.stack(np.unravel_index(cells, (gs, gs, vh)), axis=1).astype(np.int32)
    arrays = {
        "grid_feat": E.astype(np.float32),
        "grid_pos": grid_pos,
        "weight": np.ones(400, np.float32),
        "grid_rgb": rng.integers(0, 256, size=(400, 3), dtype=np.uint8),
        "gs": gs,
        "vh": vh,
    }
    write_vlmaps_h5df(folder / "vlmap" / "vlmaps.h5df", arrays)


@pytest.mark.parametrize("doc,line,code", CASES)
def test_guide_python_block_runs(doc, line, code, tmp_path, monkeypatch):
    _stand_ins(tmp_path)
    monkeypatch.chdir(tmp_path)
    before = {p.name for p in tmp_path.iterdir()}
    out = io.StringIO()
    namespace: dict = {"__name__": f"docs_{Path(doc).stem}"}
    with contextlib.redirect_stdout(out):
        exec(compile(code, f"docs/{doc}:{line}", "exec"), namespace)
    if "print(" in code:
        assert out.getvalue().strip(), f"docs/{doc}:{line} printed nothing"
    # what the block says it writes, it wrote
    for name in re.findall(r"[\"']([\w./-]+\.(?:rrd|zarr|npz|json|md|png))[\"']", code):
        if Path(name).name not in before and not name.startswith("/"):
            assert (tmp_path / name).exists(), f"docs/{doc}:{line} did not write {name}"


def test_plugin_guide_code_runs(capsys):
    blocks = [code for _, code in _python_blocks((DOCS / "plugins.md").read_text())]
    assert len(blocks) >= 4
    namespace: dict = {"__name__": "plugin_guide"}
    try:
        for block in blocks:
            exec(compile(block, "docs/plugins.md", "exec"), namespace)
    finally:
        registry.unregister("encoders", "bag-of-words")
    assert "bag-of-words" in capsys.readouterr().out


def test_config_reference_is_current():
    text = (DOCS / "config.md").read_text()
    assert config_reference() in text, (
        "regenerate docs/config.md: python -m quash_plugins.core.config"
    )


def test_concepts_lists_every_built_in_plugin():
    """docs/concepts.md's table of interfaces names each kind's built-ins, as `quash
    plugins` lists them (it once missed `auto`, `label-list`, `map-negatives` and
    `openscene`)."""
    rows = {
        m.group(1): set(re.findall(r"`([\w-]+)`", m.group(2)))
        for m in re.finditer(
            r"^\| `(\w+)` \| .+? \| (.+) \|$", (DOCS / "concepts.md").read_text(), re.M
        )
    }
    kinds = {"Encoder": "encoders", "Heuristic": "heuristics", "Classifier": "classifiers"}
    kinds["MapAdapter"] = "adapters"
    for interface, kind in kinds.items():
        built_in = {i.name for i in registry.plugins(kind) if i.dist == "quash-plugins"}
        assert rows[interface] == built_in, (interface, rows[interface] ^ built_in)
