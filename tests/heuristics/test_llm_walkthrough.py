"""What a new user of the ``llm`` heuristic meets: a proxy in the environment, a wrong
base_url or model, a reasoning model, a body that is no chat completion, a reply cut off
at the token limit, and a long run that stops at one query. Against the loopback chat
server of test_heuristics_llm."""

from __future__ import annotations

import json
import logging
import socket

import pytest
from test_heuristics_llm import make

from quash_plugins.core import registry
from quash_plugins.core.errors import HeuristicError
from quash_plugins.heuristics._llm_http import client_options, env_proxy, is_loopback

PROXY_VARS = ("HTTP_PROXY", "HTTPS_PROXY", "ALL_PROXY", "NO_PROXY")


@pytest.fixture
def dead_proxy(monkeypatch):
    """An environment whose proxy is a port nothing listens on; returns its URL."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    for name in PROXY_VARS:
        monkeypatch.delenv(name, raising=False)
        monkeypatch.delenv(name.lower(), raising=False)
    url = f"http://proxyuser:proxy-pass-99@127.0.0.1:{port}"
    monkeypatch.setenv("HTTP_PROXY", url)
    monkeypatch.setenv("HTTPS_PROXY", url)
    return url


def _chat(content, finish="stop") -> bytes:
    message = {"role": "assistant", "content": content}
    return json.dumps({"choices": [{"message": message, "finish_reason": finish}]}).encode()


def test_a_loopback_server_is_reached_past_the_environments_proxy(server, tmp_path, dead_proxy):
    """On a cluster that sets HTTP_PROXY, a local Ollama looked down: the request went to
    the proxy, and the error said 'nothing listens on 127.0.0.1:PORT' of the server."""
    qs = make(server, tmp_path, max_retries=0).expand("chair")
    assert qs.positives == ["chair", "seat", "armchair", "stool"]
    assert len(server.requests) == 1
    assert env_proxy(server.base_url) is None


@pytest.mark.parametrize(
    ("host", "loopback"),
    [("127.0.0.1", True), ("127.1.2.3", True), ("::1", True), ("[::1]", True),
     ("localhost", True), ("LOCALHOST", True), ("10.0.0.5", False), ("gpu-box", False),
     ("localhost.example.com", False), (None, False)],
)  # fmt: skip
def test_which_hosts_are_loopback(host, loopback):
    assert is_loopback(host) is loopback
    if host:
        name = host if host.startswith("[") or ":" not in host else f"[{host}]"
        assert bool(client_options(f"http://{name}:8000/v1")) is loopback


def test_a_remote_host_through_a_proxy_names_the_proxy_never_its_password(tmp_path, dead_proxy):
    """A server elsewhere is reached through the environment's proxy (NO_PROXY honoured);
    when that fails, the error names the proxy (password redacted) and NO_PROXY."""
    h = registry.create(
        "heuristics", "llm", model="m", base_url="http://gpu-box.example:8000/v1",
        max_retries=0, timeout=5.0, cache_dir=str(tmp_path / "llm"),
    )  # fmt: skip
    with pytest.raises(HeuristicError) as err:
        h.expand("chair")
    msg = str(err.value)
    port = dead_proxy.rsplit(":", 1)[1]
    assert f"connection failed through the proxy http://***@127.0.0.1:{port}" in msg
    assert "add it to NO_PROXY" in msg and "gpu-box.example" in msg
    assert "proxy-pass-99" not in msg and "nothing listens" not in msg


def test_no_proxy_is_honoured_for_a_remote_host(monkeypatch, dead_proxy):
    monkeypatch.setenv("NO_PROXY", "gpu-box.example")
    assert env_proxy("http://gpu-box.example:8000/v1/chat/completions") is None
    assert env_proxy("http://other.example/v1/chat/completions") is not None


def test_an_unknown_model_is_answered_with_the_servers_models(server, tmp_path):
    server.models = ["llama3.1:8b", "qwen2.5:7b"]
    server.play(404, raw=b'{"error": {"message": "model \\"llama3:8b\\" not found"}}')
    with pytest.raises(HeuristicError) as err:
        make(server, tmp_path, model="llama3:8b").expand("chair")
    msg = str(err.value)
    assert "does not serve model 'llama3:8b'; it serves 'llama3.1:8b', 'qwen2.5:7b'" in msg
    assert "Set model to one of them" in msg and "ollama pull llama3:8b" in msg
    assert len(server.requests) == 1  # not retried


@pytest.mark.parametrize("path", ["", "/api"])
def test_a_base_url_without_v1_is_answered_with_the_api_url(server, tmp_path, path):
    server.models = ["test-model"]
    server.play(404, raw=b"404 page not found")
    origin = server.base_url.removesuffix("/v1")
    with pytest.raises(HeuristicError) as err:
        make(server, tmp_path, base_url=origin + path).expand("chair")
    msg = str(err.value)
    assert f"The API is at {origin}/v1, not under {path or '/'}: set base_url: {origin}/v1" in msg
    assert server.requests[0]["path"] == f"{path}/chat/completions"
    assert server.gets == [f"{path}/models", "/v1/models"]


def test_a_404_from_a_server_without_a_model_list_still_says_what_to_check(server, tmp_path):
    server.play(404, raw=b"no route")
    origin = server.base_url.removesuffix("/v1")
    with pytest.raises(HeuristicError) as err:
        make(server, tmp_path, base_url=origin).expand("chair")
    assert f"(base_url: {origin}/v1?) and the model name" in str(err.value)
    server.play(404, raw=b"no route")
    with pytest.raises(HeuristicError, match=r"Check base_url \(it usually ends in /v1\)"):
        make(server, tmp_path).expand("chair")


@pytest.mark.parametrize(
    "reply",
    [
        # a draft in the thoughts used to be taken as the answer: synonyms ['x'],
        # antonyms ['chair'] (the query, dropped) -> a wrong set, cached
        '<think>Draft: {"synonyms": ["x"], "antonyms": ["table"]}. Better:</think>\n'
        '{"synonyms": ["seat", "stool"], "antonyms": ["desk", "lamp"]}',
        # the template opened the thoughts; only the closing tag is in the reply
        "Synonyms: x, y. Hmm, and antonyms: table.\n</think>\n\n```json\n"
        '{"synonyms": ["seat", "stool"], "antonyms": ["desk", "lamp"]}\n```',
        "<thinking>\nSynonyms:\n- x\n</thinking>\nSynonyms: seat, stool\nAntonyms: desk, lamp",
    ],
)
def test_a_reasoning_models_thoughts_are_not_its_answer(server, tmp_path, reply):
    server.default = reply
    qs = make(server, tmp_path).expand("chair")
    assert qs.positives == ["chair", "seat", "stool"] and qs.negatives == ["desk", "lamp"]


def test_thoughts_cut_off_at_the_token_limit_say_so_and_are_not_cached(server, tmp_path):
    server.play(raw=_chat('<think>Synonyms: seat, stool. Antonyms: {"synonyms"', "length"))
    h = make(server, tmp_path, max_retries=0)
    with pytest.raises(HeuristicError) as err:
        h.expand("chair")
    msg = str(err.value)
    assert "holds only the model's reasoning" in msg and "finish_reason 'length'" in msg
    assert "stopped at its token limit" in msg and "num_ctx" in msg
    assert "json_mode" not in msg
    assert not h.cache_path("chair").exists()


def test_a_reply_cut_off_mid_list_says_token_limit(server, tmp_path):
    server.play(raw=_chat('{"synonyms": ["seat", "stool", "arm', "length"))
    with pytest.raises(HeuristicError) as err:
        make(server, tmp_path, max_retries=0).expand("chair")
    assert "stopped at its token limit" in str(err.value)


@pytest.mark.parametrize(
    "body", [b"<html><body>Open WebUI</body></html>", b'{"status": "ok", "models": []}']
)
def test_a_body_that_is_no_chat_completion_points_at_base_url(server, tmp_path, body):
    """A web page or another JSON API at base_url: the fix is base_url (it said to set
    json_mode or use an instruction-tuned model)."""
    server.play(raw=body)
    with pytest.raises(HeuristicError) as err:
        make(server, tmp_path, max_retries=0).expand("chair")
    msg = str(err.value)
    assert "The body is not a chat completion" in msg and "Set base_url" in msg
    assert "json_mode" not in msg


def test_a_long_run_that_stops_at_one_query_keeps_the_others(server, tmp_path):
    h = make(server, tmp_path, max_retries=1)
    h.expand("chair")
    h.expand("sofa")
    for _ in range(2):
        server.play(content="I am sorry, I cannot help with that.")
    with pytest.raises(HeuristicError) as err:
        h.expand("lamp")
    msg = str(err.value)
    assert "last: status 200 with an unusable reply" in msg
    assert f"The 2 query set(s) this run got from the server before 'lamp' are cached in {tmp_path / 'llm'}" in msg  # fmt: skip
    assert sorted(p.name for p in (tmp_path / "llm").glob("*.json")) == sorted(
        h.cache_path(q).name for q in ("chair", "sofa")
    )  # the failure is not cached
    asked = len(server.requests)
    again = make(server, tmp_path)
    assert again.expand("chair").provenance["source"] == "cache"
    assert again.expand("lamp").provenance["source"] == "server"
    assert len(server.requests) == asked + 1


def test_a_first_failure_says_nothing_about_a_cache(server, tmp_path):
    server.play(503, raw=b"busy")
    with pytest.raises(HeuristicError) as err:
        make(server, tmp_path, max_retries=0).expand("chair")
    assert "re-run asks only" not in str(err.value)


def test_a_short_answer_is_logged_with_the_counts(server, tmp_path, caplog):
    caplog.set_level(logging.INFO, logger="quash_plugins")
    # GOOD: 3 synonyms left (seat, armchair, stool); 3 antonyms (table, lamp, rug)
    make(server, tmp_path, n_synonyms=3, n_antonyms=5).expand("chair")
    assert "'chair': the model gave 3 of 3 synonyms and 3 of 5 antonyms" in caplog.text
    caplog.clear()
    make(server, tmp_path, n_synonyms=3, n_antonyms=3).expand("sofa")
    assert "the model gave" not in caplog.text
