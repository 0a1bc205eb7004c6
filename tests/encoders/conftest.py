"""Shared fixtures for the encoder tests: one MiniLM per test session."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="session")
def minilm():
    """The real all-MiniLM-L6-v2 encoder on CPU, loaded once per test session."""
    pytest.importorskip("sentence_transformers")
    from quash_plugins.encoders._sentence_transformers import MiniLMEncoder

    enc = MiniLMEncoder(device="cpu")
    enc.encode_text(["warm up"])
    return enc
