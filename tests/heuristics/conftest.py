"""Fixtures of the heuristics tests: a private cache folder, and the loopback servers."""

from __future__ import annotations

import pytest


@pytest.fixture(autouse=True)
def _cache_env(tmp_path, monkeypatch):
    """Every cache (text embeddings, LLM query sets) under the test's own folder."""
    monkeypatch.setenv("QUASH_CACHE_DIR", str(tmp_path / "quash-cache"))


@pytest.fixture
def server():
    """The scripted chat-completions server of test_heuristics_llm, on 127.0.0.1."""
    from test_heuristics_llm import ChatServer

    s = ChatServer()
    yield s
    s.close()


@pytest.fixture
def raw():
    """``raw(handler)`` starts a RawServer of test_llm_http_limits (a socket server whose
    handler writes the reply bytes itself) on 127.0.0.1; every one is closed after."""
    from test_llm_http_limits import RawServer

    servers: list[RawServer] = []

    def start(handler) -> RawServer:
        servers.append(RawServer(handler))
        return servers[-1]

    yield start
    for s in servers:
        s.close()
