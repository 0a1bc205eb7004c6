"""The ``llm`` heuristic against servers that misbehave as real ones do: a server that
closes the connection (before a reply, or in the middle of one), a rate limit whose
wait is logged, and a model that lists the query (in the plural, with an article) among
its antonyms. On 127.0.0.1, through the servers of test_heuristics_llm and
test_llm_http_limits."""

from __future__ import annotations

import json
import logging
import socket
import time

import pytest
from test_heuristics_llm import _completion, make
from test_llm_http_limits import _make

from quash_plugins.core.errors import HeuristicError

pytest.importorskip("httpx")


def _hang_up(handler, server) -> None:
    """Read the request, answer nothing, close the connection."""
    handler.connection.shutdown(socket.SHUT_RDWR)


def _half_reply(handler, server) -> None:
    """Promise a whole completion, send half of it, close the connection."""
    body = _completion('{"synonyms": ["seat"], "antonyms": ["table"]}')
    handler.send_response(200)
    handler.send_header("Content-Type", "application/json")
    handler.send_header("Content-Length", str(len(body)))
    handler.end_headers()
    handler.wfile.write(body[: len(body) // 2])
    handler.wfile.flush()
    handler.connection.shutdown(socket.SHUT_RDWR)


@pytest.mark.parametrize(
    ("handler", "words"),
    [
        (_hang_up, "RemoteProtocolError: Server disconnected without sending a response."),
        (_half_reply, "RemoteProtocolError: peer closed connection without sending complete"),
    ],
)
def test_a_server_that_hangs_up_is_not_told_to_start(raw, tmp_path, caplog, handler, words):
    """A server that took the request and closed the connection is running: the error
    said 'connection failed (...)' and 'Start the server ... or set base_url to where it
    listens', which sent users to check a server that was up (it had crashed on the
    request, or run out of memory loading the model). Retried, bounded, nothing cached."""
    s = raw(handler)
    h = _make(s.base_url, tmp_path, max_retries=1)
    caplog.set_level(logging.INFO, logger="quash_plugins")
    with pytest.raises(HeuristicError) as err:
        h.expand("chair")
    msg = str(err.value)
    assert len(s.requests) == 2
    assert h.endpoint in msg and "after 2 attempt(s)" in msg
    assert f"last: the server closed the connection before a whole reply ({words}" in msg
    assert "see the server's log, raise max_retries" in msg
    assert "Start the server" not in msg and "nothing listens" not in msg
    warned = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warned) == 2 and all("the server closed the connection" in w for w in warned)
    assert not list((tmp_path / "llm").glob("*.json"))


def test_each_retry_says_how_long_it_waits(server, tmp_path, caplog):
    """A 429 with Retry-After: 1 was logged as 'status 429: ...' and then nothing for the
    wait (up to 60 s a try): the warning now says when the next attempt comes. The last
    failed attempt has no next one, and says none."""
    server.play(
        429, raw=b'{"error": {"message": "Rate limit reached"}}', headers={"Retry-After": "1"}
    )
    server.play(500, raw=b'{"error": "boom"}')
    server.play(500, raw=b'{"error": "boom"}')
    caplog.set_level(logging.WARNING, logger="quash_plugins")
    with pytest.raises(HeuristicError, match="after 3 attempt"):
        make(server, tmp_path, max_retries=2, backoff=0.05).expand("chair")
    warned = [r.getMessage() for r in caplog.records if r.name.endswith("_llm")]
    assert warned == [
        f"llm: {server.base_url}/chat/completions status 429: "
        '\'{"error": {"message": "Rate limit reached"}}\'; retrying in 1 s',
        f'llm: {server.base_url}/chat/completions status 500: \'{{"error": "boom"}}\'; '
        "retrying in 0.1 s",
        f'llm: {server.base_url}/chat/completions status 500: \'{{"error": "boom"}}\'',
    ]
    assert server.times[1] - server.times[0] >= 0.95


def test_the_query_in_another_number_is_no_antonym(server, tmp_path):
    """'chairs' and 'a chair' among the antonyms of 'chair' were kept as negatives, and
    cached: the classifier was trained to reject the very thing asked for. So were
    'seats' for the synonym 'seat'. Dropped as the query itself is."""
    server.default = (
        '{"synonyms": ["seat", "Chairs", "stool"], '
        '"antonyms": ["chairs", "A Chair", "seats", "tables", "lamp"]}'
    )
    h = make(server, tmp_path)
    qs = h.expand("chair")
    assert qs.positives == ["chair", "seat", "chairs", "stool"]
    assert qs.negatives == ["tables", "lamp"]
    again = make(server, tmp_path).expand("chair")  # from the cache, as cleaned
    assert again.provenance["source"] == "cache" and again.negatives == ["tables", "lamp"]


def _cut(content: str) -> bytes:
    """A chat completion that stopped at the token limit."""
    message = {"role": "assistant", "content": content}
    return json.dumps({"choices": [{"message": message, "finish_reason": "length"}]}).encode()


@pytest.mark.parametrize(
    "reply",
    ["Synonyms:\n1. seat\n2. stool\nAntonyms:\n1. table\n2. la", "Synonyms: seat, stool, arm"],
)
def test_a_list_cut_at_the_token_limit_is_not_taken_or_cached(server, tmp_path, reply):
    """A model that answers in lines or commas and stops at its token limit: the lists
    read up to the cut were taken (antonyms ['table', 'la'], a synonym 'arm') and cached,
    so every later run served the cut set. Now the failure says 'token limit'."""
    server.play(raw=_cut(reply))
    h = make(server, tmp_path, max_retries=0)
    with pytest.raises(HeuristicError) as err:
        h.expand("chair")
    msg = str(err.value)
    assert "no whole JSON lists before the cut" in msg and "finish_reason 'length'" in msg
    assert "stopped at its token limit" in msg
    assert not h.cache_path("chair").exists()


def test_a_whole_json_object_before_the_token_limit_is_used(server, tmp_path):
    server.play(raw=_cut('{"synonyms": ["seat"], "antonyms": ["table"]}\nAlso, a'))
    qs = make(server, tmp_path, max_retries=0).expand("chair")
    assert qs.positives == ["chair", "seat"] and qs.negatives == ["table"]


@pytest.mark.parametrize(
    "reply", ['{"synonyms": [], "antonyms": []}', '{"synonyms": ["Chair"], "antonyms": ["chairs"]}']
)
def test_an_empty_reply_is_one_warning_naming_the_endpoint(server, tmp_path, caplog, reply):
    """Two warnings said it ('empty reply for 'chair' is not cached', then 'test-model
    returned no synonyms and no antonyms'), and neither named the endpoint."""
    server.default = reply
    caplog.set_level(logging.WARNING, logger="quash_plugins")
    h = make(server, tmp_path)
    qs = h.expand("chair")
    assert qs.positives == ["chair"] and qs.negatives == []
    warned = [r.getMessage() for r in caplog.records]
    assert warned == [
        f"llm: {h.endpoint} (test-model) returned no synonyms and no antonyms for 'chair': "
        "the query alone is the positive; not cached, so the next run asks again"
    ]
    assert not h.cache_path("chair").exists()


def test_an_empty_cached_set_says_which_file(server, tmp_path, caplog):
    """A cache file emptied by hand: the warning named the model as if the server had
    answered; it names the file to delete."""
    h = make(server, tmp_path)
    path = h._write_cache("chair", [], [])
    caplog.set_level(logging.WARNING, logger="quash_plugins")
    qs = h.expand("chair")
    assert qs.provenance["source"] == "cache" and qs.positives == ["chair"]
    assert [r.getMessage() for r in caplog.records] == [
        f"llm: the cached set for 'chair' ({path}) holds no synonyms and no antonyms"
    ]
    assert server.requests == []


def test_https_to_a_plain_http_server_says_to_use_http(server, tmp_path):
    """base_url https:// for a local server: the error was 'connection failed
    (ConnectError: [SSL: WRONG_VERSION_NUMBER] ...)' with 'Start the server', for a
    server that was up, after every retry's backoff. Now it says so at the first try."""
    url = server.base_url.replace("http://", "https://")
    h = _make(url, tmp_path, max_retries=4, backoff=1.0)
    t = time.monotonic()
    with pytest.raises(HeuristicError) as err:
        h.expand("chair")
    assert time.monotonic() - t < 2.0  # not retried: 1 + 2 + 4 + 8 s of backoff for nothing
    msg = str(err.value)
    assert "after 1 attempt(s)" in msg
    netloc = url.split("/")[2]
    assert f"last: TLS handshake failed: {netloc} answers plain http, not https" in msg
    assert f"set base_url: {server.base_url}," in msg
    assert "Start the server" not in msg and server.requests == []


def test_an_untrusted_certificate_says_ssl_cert_file(tmp_path, monkeypatch):
    import httpx

    from quash_plugins.heuristics import _llm

    def refuse(*args, **kwargs):
        raise httpx.ConnectError(
            "[SSL: CERTIFICATE_VERIFY_FAILED] certificate verify failed: self-signed "
            "certificate (_ssl.c:1006)"
        )

    monkeypatch.setattr(_llm, "bounded_request", refuse)
    for name in ("HTTP_PROXY", "HTTPS_PROXY", "ALL_PROXY"):  # no proxy named in the reason
        monkeypatch.delenv(name, raising=False)
        monkeypatch.delenv(name.lower(), raising=False)
    h = _make("https://llm.lab.example/v1", tmp_path)
    with pytest.raises(HeuristicError) as err:
        h.expand("chair")
    msg = str(err.value)
    assert "TLS handshake failed: the certificate of llm.lab.example is not trusted" in msg
    assert "set SSL_CERT_FILE to the CA bundle that signed it" in msg
    assert "Start the server" not in msg


@pytest.mark.parametrize(
    ("given", "meant"),
    [
        ("127.0.0.1:11434/v1", "http://127.0.0.1:11434/v1"),
        ("localhost:8000/v1/", "http://localhost:8000/v1/"),
        ("gpu-box:8080/v1?key=s3cret-value", "http://gpu-box:8080/v1?key=***"),
    ],
)
def test_a_base_url_without_a_scheme_is_answered_with_one(given, meant):
    """'localhost:8000/v1' was refused as 'not an http(s) URL' with three examples; the
    message now gives the URL meant (query values hidden)."""
    from quash_plugins.core.errors import ConfigError
    from quash_plugins.heuristics._llm import LLMHeuristic

    with pytest.raises(ConfigError) as err:
        LLMHeuristic(model="m", base_url=given)
    msg = str(err.value)
    assert f"is not an http(s) URL. Did you mean base_url: {meant}?" in msg
    assert "s3cret-value" not in msg


def test_a_base_url_that_is_no_url_at_all_gets_no_guess():
    from quash_plugins.core.errors import ConfigError
    from quash_plugins.heuristics._llm import LLMHeuristic

    with pytest.raises(ConfigError) as err:
        LLMHeuristic(model="m", base_url="ftp://files/v1")
    msg = str(err.value)
    assert "Did you mean" not in msg and "E.g. http://127.0.0.1:8000/v1" in msg


def test_a_message_given_as_content_parts_is_read(server, tmp_path):
    """Some gateways answer with the message as a list of parts; it failed as 'message
    content is list' on every attempt."""
    parts = [
        {"type": "text", "text": '{"synonyms": ["seat"], '},
        {"type": "text", "text": '"antonyms": ["table"]}'},
    ]
    message = {"role": "assistant", "content": parts}
    server.play(
        raw=json.dumps({"choices": [{"message": message, "finish_reason": "stop"}]}).encode()
    )
    qs = make(server, tmp_path, max_retries=0).expand("chair")
    assert qs.positives == ["chair", "seat"] and qs.negatives == ["table"]


def test_cache_file_is_shown_only_when_written(server, tmp_path, caplog):
    """The provenance named a cache_file for a set that was never written (an empty
    reply, or a cache folder that cannot be made), and docs say to delete that file to
    ask again; and a later failure said the unwritten sets 'are cached'."""
    server.default = '{"synonyms": [], "antonyms": []}'
    qs = make(server, tmp_path).expand("chair")
    assert "cache_file" not in qs.provenance and qs.provenance["source"] == "server"

    server.default = '{"synonyms": ["seat"], "antonyms": ["table"]}'
    blocked = tmp_path / "not-a-folder"
    blocked.write_text("a file where the cache folder would be")
    h = make(server, tmp_path, cache_dir=str(blocked / "llm"), max_retries=0)
    qs = h.expand("chair")
    assert qs.positives == ["chair", "seat"] and "cache_file" not in qs.provenance
    server.play(503, raw=b"{}")
    with pytest.raises(HeuristicError) as err:
        h.expand("sofa")
    assert "are cached" not in str(err.value)


def test_a_400_about_the_model_lists_the_servers_models(server, tmp_path):
    """A gateway that answers an unknown model with 400 (LiteLLM: 'Invalid model name
    passed in model=gpt4o') got no hint at all; it now gets the 404's: the models the
    server serves."""
    server.models = ["gpt-4o", "gpt-4o-mini"]
    server.play(400, raw=b'{"error": {"message": "Invalid model name passed in model=gpt4o"}}')
    with pytest.raises(HeuristicError) as err:
        make(server, tmp_path, model="gpt4o").expand("chair")
    msg = str(err.value)
    assert """answered status 400: '{"error": {"message": "Invalid model name""" in msg
    assert "The server does not serve model 'gpt4o'; it serves 'gpt-4o', 'gpt-4o-mini'." in msg
    assert server.gets == ["/v1/models"] and len(server.requests) == 1


def test_a_400_about_something_else_asks_for_no_model_list(server, tmp_path):
    server.models = ["test-model"]
    server.play(400, raw=b'{"error": "temperature must be <= 2"}')
    with pytest.raises(HeuristicError) as err:
        make(server, tmp_path).expand("chair")
    assert "does not serve" not in str(err.value) and server.gets == []
