"""Weights are named by what they are, not where they lie (encoders/_runtime.py)."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import struct

import numpy as np
import pytest

from quash_plugins.encoders._runtime import (
    content_digest,
    legacy_weights_identity,
    weights_identity,
)


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("QUASH_CACHE_DIR", str(tmp_path / "cache"))


def _safetensors(n: int, seed: int) -> bytes:
    header = json.dumps({"w": {"dtype": "F32", "shape": [n], "data_offsets": [0, 4 * n]}})
    body = np.random.default_rng(seed).standard_normal(n).astype(np.float32).tobytes()
    return struct.pack("<Q", len(header)) + header.encode() + body


def _model(folder, seed=0):
    folder.mkdir(parents=True)
    (folder / "config.json").write_text('{"hidden": 8}')
    (folder / "model.safetensors").write_bytes(_safetensors(64, seed))
    return folder


def test_content_digest_is_the_files_sha256(tmp_path):
    f = _model(tmp_path / "m") / "model.safetensors"
    assert content_digest(f) == hashlib.sha256(f.read_bytes()).hexdigest()[:16]


def test_the_same_weights_elsewhere_and_reinstalled_have_one_identity(tmp_path):
    a = _model(tmp_path / "venv-a" / "model")
    b = tmp_path / "venv-b" / "model"
    shutil.copytree(a, b)
    os.utime(b / "model.safetensors", ns=(1, 10**18))  # a reinstall: a new mtime
    assert weights_identity(a) == weights_identity(b)
    assert "path" not in weights_identity(a)
    # the earlier naming told them apart: path and mtime
    assert legacy_weights_identity(a) != legacy_weights_identity(b)


def test_other_weights_of_the_same_shape_and_mtime_differ(tmp_path):
    """Two fine-tunes of one architecture: one size, one safetensors header."""
    a, b = _model(tmp_path / "a", seed=0), _model(tmp_path / "b", seed=1)
    st = (a / "model.safetensors").stat()
    os.utime(b / "model.safetensors", ns=(st.st_atime_ns, st.st_mtime_ns))
    assert (a / "model.safetensors").stat().st_size == (b / "model.safetensors").stat().st_size
    assert legacy_weights_identity(a)["sha"] == legacy_weights_identity(b)["sha"]
    assert weights_identity(a) != weights_identity(b)


def test_a_file_is_read_once_and_again_when_it_changes(tmp_path):
    f = _model(tmp_path / "m") / "model.safetensors"
    real = content_digest(f)
    [memo] = (tmp_path / "cache" / "weight-digests").iterdir()
    assert memo.read_text().strip() == real
    memo.write_text("0123456789abcdef\n")  # what a second read would not give
    assert content_digest(f) == "0123456789abcdef"  # remembered, not read
    f.write_bytes(_safetensors(64, seed=7))  # changed: a new size/mtime key
    assert content_digest(f) == hashlib.sha256(f.read_bytes()).hexdigest()[:16]


def test_an_unwritable_memo_only_costs_a_read(tmp_path, monkeypatch):
    blocker = tmp_path / "not-a-folder"
    blocker.write_text("x")
    monkeypatch.setenv("QUASH_CACHE_DIR", str(blocker))
    f = _model(tmp_path / "m") / "model.safetensors"
    assert content_digest(f) == hashlib.sha256(f.read_bytes()).hexdigest()[:16]


def test_a_planted_memo_link_is_not_followed(tmp_path):
    f = _model(tmp_path / "m") / "model.safetensors"
    real = content_digest(f)
    [memo] = (tmp_path / "cache" / "weight-digests").iterdir()
    planted = tmp_path / "planted"
    planted.write_text("0123456789abcdef\n")
    memo.unlink()
    memo.symlink_to(planted)
    assert content_digest(f) == real
    assert planted.read_text() == "0123456789abcdef\n"  # not written through either
