"""Every command of README.md and docs/quickstart.md runs as written.

Each ```bash block runs in order, in one working folder per document, as a user would
type it after ``make demo`` (the environment's ``bin`` on ``PATH``); each ```python block
runs there too. A block that cannot run here is marked in the Markdown, on the line
before it, with ``<!-- doc-test: skip (the reason) -->`` and is skipped with that
reason (downloaded weights, a display, the set-up itself).
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
DOCS = ("README.md", "docs/quickstart.md")
SKIP = re.compile(r"<!--\s*doc-test:\s*skip\s*\((?P<reason>.+)\)\s*-->")


@dataclass
class Block:
    doc: str
    line: int
    lang: str
    code: str
    skip: str | None

    @property
    def id(self) -> str:
        return f"{self.doc}:{self.line}"


def blocks(doc: str) -> list[Block]:
    """The bash and python blocks of ``doc``, with the skip reason marked before each."""
    lines = (REPO / doc).read_text(encoding="utf-8").splitlines()
    out, i = [], 0
    while i < len(lines):
        m = re.fullmatch(r"```(\w+)\s*", lines[i])
        if not m:
            i += 1
            continue
        j = i + 1
        while not lines[j].startswith("```"):
            j += 1
        prev = next((ln for ln in reversed(lines[:i]) if ln.strip()), "")
        skip = SKIP.fullmatch(prev.strip())
        if m.group(1) in ("bash", "sh", "python"):
            lang = "python" if m.group(1) == "python" else "bash"
            code = "\n".join(lines[i + 1 : j]) + "\n"
            out.append(Block(doc, i + 1, lang, code, skip.group("reason") if skip else None))
        i = j + 1
    return out


ALL = [b for doc in DOCS for b in blocks(doc)]


def test_the_documents_have_commands_and_every_skip_has_a_reason():
    for doc in DOCS:
        found = blocks(doc)
        assert any(b.skip is None and b.lang == "bash" for b in found), doc
    text = "\n".join((REPO / d).read_text() for d in DOCS)
    assert len(re.findall(r"doc-test:\s*skip", text)) == len(SKIP.findall(text))


@pytest.fixture(scope="module")
def workdirs(tmp_path_factory) -> dict[str, Path]:
    """One working folder per document (its blocks build on each other) and one cache."""
    cache = tmp_path_factory.mktemp("doc-cache")
    return {"cache": cache, **{doc: tmp_path_factory.mktemp(Path(doc).stem) for doc in DOCS}}


@pytest.mark.slow
@pytest.mark.parametrize("block", ALL, ids=[b.id for b in ALL])
def test_block_runs_as_written(block: Block, workdirs):
    if block.skip:
        pytest.skip(block.skip)
    bindir = str(Path(sys.executable).parent)
    env = {
        **os.environ,
        "PATH": bindir + os.pathsep + os.environ.get("PATH", ""),
        "QUASH_CACHE_DIR": str(workdirs["cache"]),
        "COLUMNS": "100",
    }
    if block.lang == "bash":
        cmd = ["bash", "-e", "-o", "pipefail", "-c", block.code]
    else:
        cmd = [sys.executable, "-c", block.code]
    proc = subprocess.run(
        cmd,
        cwd=workdirs[block.doc],
        env=env,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert proc.returncode == 0, (
        f"{block.id} failed ({proc.returncode}):\n{block.code}\n--- stdout\n"
        f"{proc.stdout[-3000:]}\n--- stderr\n{proc.stderr[-3000:]}"
    )


PY_EXAMPLES = [b for b in ALL if b.lang == "python" and "result.instances" in b.code]


@pytest.mark.parametrize("block", PY_EXAMPLES, ids=[b.id for b in PY_EXAMPLES])
def test_python_examples_that_show_instances_find_some(block, minilm_scene, tmp_path, monkeypatch):
    """The README's and the quickstart's Python examples show ``result.instances`` (the
    groups a robot goes to) with the shipped ``demo:quash-labels``, whose ``instances:
    false`` made them always ``[]``; they run here on a make-scene map, with the shipped
    config, and the chair they ask for is found as objects."""
    import contextlib
    import io
    import shutil

    assert not block.skip, block.id
    for name in ("scene.npz", "scene.taxonomy.yaml"):
        shutil.copy(minilm_scene.with_name(name), tmp_path / name)
    monkeypatch.chdir(tmp_path)
    namespace: dict = {"__name__": "doc_example"}
    with contextlib.redirect_stdout(io.StringIO()):
        exec(compile(block.code, block.id, "exec"), namespace)
    results = [v for v in namespace.values() if type(v).__name__ == "QueryResult"]
    assert results, f"{block.id} left no result to look at"
    for result in results:
        assert result.n_matched and result.instances, (block.id, result)
        sizes = [inst.size for inst in result.instances]
        assert sum(sizes) <= result.n_matched and sizes == sorted(sizes, reverse=True)
