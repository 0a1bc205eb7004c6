"""The ``table`` encoder's fingerprint: what keys its cached rows."""

from __future__ import annotations

import numpy as np


def test_relabelled_table_is_another_fingerprint(tmp_path):
    """The fingerprint hashed the embeddings and the file name, not the texts: a table
    rewritten in place with two rows' texts swapped kept its fingerprint, so the text
    cache served 'chair' the row that is now 'sofa''s."""
    from quash_plugins.encoders import TableEncoder

    path = tmp_path / "text.npz"
    emb = np.random.default_rng(0).normal(size=(3, 8)).astype(np.float32)
    np.savez(path, texts=np.asarray(["chair", "sofa", "other"]), embeddings=emb)
    before = TableEncoder(file=str(path))
    np.savez(path, texts=np.asarray(["sofa", "chair", "other"]), embeddings=emb)
    after = TableEncoder(file=str(path))
    assert not np.allclose(before.encode_text(["chair"]), after.encode_text(["chair"]))
    assert before.fingerprint() != after.fingerprint()
    np.savez(path, texts=np.asarray(["sofa", "chair", "other"]), embeddings=emb)
    assert TableEncoder(file=str(path)).fingerprint() == after.fingerprint()
