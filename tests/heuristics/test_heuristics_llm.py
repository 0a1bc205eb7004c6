"""The ``llm`` heuristic against a real chat-completions server on loopback."""

from __future__ import annotations

import json
import logging
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import numpy as np
import pytest

from quash_plugins.core import registry
from quash_plugins.core.errors import ConfigError, HeuristicError
from quash_plugins.core.interfaces import ExpansionContext
from quash_plugins.heuristics._llm import PROMPT_VERSION, LLMHeuristic, chat_endpoint

SECRET = "sk-test-not-a-real-key-1234567890"


def _completion(content: str) -> bytes:
    return json.dumps(
        {
            "id": "chatcmpl-test",
            "object": "chat.completion",
            "model": "test-model",
            "choices": [
                {
                    "index": 0,
                    "message": {"role": "assistant", "content": content},
                    "finish_reason": "stop",
                }
            ],
        }
    ).encode()


GOOD = json.dumps(
    {
        "synonyms": ["seat", "armchair", "Seat", "stool", "chair"],
        "antonyms": ["table", "chair", "lamp", "stool", "rug"],
    }
)


class ChatServer:
    """A tiny chat-completions server; ``script`` holds the replies to play, in order.

    Each entry is ``(status, body_bytes, headers, delay_s)``; when the script is empty the
    server answers ``default`` with status 200. ``GET /v1/models`` lists ``models`` (404
    while it is None, and on any other path); GET paths are kept in ``gets``.
    """

    def __init__(self) -> None:
        self.script: list[tuple[int, bytes, dict[str, str], float]] = []
        self.default = GOOD
        self.models: list[str] | None = None
        self.requests: list[dict] = []  # the POSTs
        self.gets: list[str] = []
        self.times: list[float] = []
        outer = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args):  # keep test output clean
                pass

            def do_GET(self):  # noqa: N802 - http.server API
                outer.gets.append(self.path)
                if self.path == "/v1/models" and outer.models is not None:
                    rows = [{"id": m, "object": "model"} for m in outer.models]
                    status, payload = 200, json.dumps({"object": "list", "data": rows}).encode()
                else:
                    status, payload = 404, b"404 page not found"
                self.send_response(status)
                self.send_header("Content-Length", str(len(payload)))
                self.end_headers()
                self.wfile.write(payload)

            def do_POST(self):  # noqa: N802 - http.server API
                length = int(self.headers.get("Content-Length", 0))
                body = json.loads(self.rfile.read(length) or b"{}")
                outer.requests.append(
                    {"path": self.path, "headers": dict(self.headers), "body": body}
                )
                outer.times.append(time.monotonic())
                if outer.script:
                    status, payload, headers, delay = outer.script.pop(0)
                else:
                    status, payload, headers, delay = 200, _completion(outer.default), {}, 0.0
                if delay:
                    time.sleep(delay)
                try:
                    self.send_response(status)
                    self.send_header("Content-Type", "application/json")
                    self.send_header("Content-Length", str(len(payload)))
                    for k, v in headers.items():
                        self.send_header(k, v)
                    self.end_headers()
                    self.wfile.write(payload)
                except (BrokenPipeError, ConnectionResetError):
                    pass

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.httpd.daemon_threads = True
        self.thread = threading.Thread(
            target=self.httpd.serve_forever, kwargs={"poll_interval": 0.02}, daemon=True
        )
        self.thread.start()
        self.base_url = f"http://127.0.0.1:{self.httpd.server_address[1]}/v1"

    def play(
        self,
        status: int = 200,
        content: str | None = None,
        raw: bytes | None = None,
        headers: dict[str, str] | None = None,
        delay: float = 0.0,
    ) -> None:
        payload = raw if raw is not None else _completion(content if content is not None else GOOD)
        self.script.append((status, payload, headers or {}, delay))

    def close(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()


def make(server, tmp_path, **kw):
    params = dict(
        model="test-model",
        base_url=server.base_url,
        timeout=2.0,
        max_retries=2,
        backoff=0.01,
        cache_dir=str(tmp_path / "llm"),
    )
    params.update(kw)
    return registry.create("heuristics", "llm", **params)


def test_success_parses_and_cleans(server, tmp_path):
    qs = make(server, tmp_path).expand("chair", ExpansionContext(seed=3))
    assert qs.positives == ["chair", "seat", "armchair", "stool"]
    # query and synonyms removed from antonyms, order kept
    assert qs.negatives == ["table", "lamp", "rug"]
    req = server.requests[0]
    assert req["path"] == "/v1/chat/completions"
    assert req["body"]["model"] == "test-model"
    assert req["body"]["seed"] == 3
    assert [m["role"] for m in req["body"]["messages"]] == ["system", "user"]
    assert '"chair"' in req["body"]["messages"][1]["content"]
    assert "response_format" not in req["body"]
    assert qs.provenance["heuristic"] == "llm"
    assert qs.provenance["prompt_version"] == PROMPT_VERSION
    assert qs.provenance["source"] == "server"


def test_json_mode_and_counts_in_prompt(server, tmp_path):
    make(server, tmp_path, json_mode=True, n_synonyms=7, n_antonyms=9).expand("sofa")
    body = server.requests[0]["body"]
    assert body["response_format"] == {"type": "json_object"}
    assert "7" in body["messages"][1]["content"] and "9" in body["messages"][1]["content"]


def test_counts_cap_the_lists(server, tmp_path):
    qs = make(server, tmp_path, n_synonyms=1, n_antonyms=2).expand("chair")
    assert qs.positives == ["chair", "seat"]
    assert qs.negatives == ["table", "lamp"]


def test_500_then_success(server, tmp_path):
    server.play(500, raw=b'{"error": "boom"}')
    qs = make(server, tmp_path).expand("chair")
    assert len(server.requests) == 2
    assert "seat" in qs.positives


def test_429_honours_retry_after(server, tmp_path):
    server.play(429, raw=b'{"error": "slow down"}', headers={"Retry-After": "0.3"})
    qs = make(server, tmp_path, backoff=0.001).expand("chair")
    assert len(server.requests) == 2
    assert server.times[1] - server.times[0] >= 0.28
    assert "seat" in qs.positives


def test_timeout_then_success(server, tmp_path):
    server.play(delay=1.0)  # longer than the client's time-out
    t = time.monotonic()
    qs = make(server, tmp_path, timeout=0.3).expand("chair")
    assert time.monotonic() - t < 1.5
    assert len(server.requests) == 2
    assert "seat" in qs.positives


def test_retries_exhausted_names_endpoint_and_status(server, tmp_path):
    for _ in range(3):
        server.play(503, raw=b"{}")
    h = make(server, tmp_path, max_retries=2)
    with pytest.raises(HeuristicError) as err:
        h.expand("chair")
    msg = str(err.value)
    assert h.endpoint in msg and "status 503" in msg and "3 attempt" in msg
    assert len(server.requests) == 3


def test_timeouts_exhausted(server, tmp_path):
    server.play(delay=0.6)
    server.play(delay=0.6)
    with pytest.raises(HeuristicError, match="timed out"):
        make(server, tmp_path, timeout=0.2, max_retries=1).expand("chair")


def test_malformed_reply_then_good(server, tmp_path):
    server.play(raw=b"this is not json at all")
    qs = make(server, tmp_path).expand("chair")
    assert "seat" in qs.positives and len(server.requests) == 2


def test_malformed_reply_error(server, tmp_path):
    for _ in range(2):
        server.play(content="I am sorry, I cannot help with that request.")
    with pytest.raises(HeuristicError, match="unusable reply"):
        make(server, tmp_path, max_retries=1).expand("chair")
    # nothing cached for a failure
    assert not list((tmp_path / "llm").glob("*.json"))


def test_client_error_is_not_retried(server, tmp_path):
    server.play(404, raw=b'{"error": "model not found"}')
    with pytest.raises(HeuristicError, match="status 404.*model not found"):
        make(server, tmp_path).expand("chair")
    assert len(server.requests) == 1


def test_empty_lists(server, tmp_path):
    server.default = '{"synonyms": [], "antonyms": []}'
    h = make(server, tmp_path)
    qs = h.expand("chair")
    assert qs.positives == ["chair"] and qs.negatives == []
    assert not h.cache_path("chair").exists()  # an empty reply is not frozen in the cache


def test_prose_around_json_block(server, tmp_path):
    server.default = (
        "Of course! Here are the words you asked for:\n```json\n"
        '{"synonyms": ["seat", "stool"], "antonyms": ["desk"]}\n```\nLet me know if ...'
    )
    qs = make(server, tmp_path).expand("chair")
    assert qs.positives == ["chair", "seat", "stool"] and qs.negatives == ["desk"]


def test_numbered_list_reply(server, tmp_path):
    server.default = "Synonyms:\n1. Seat\n2. stool\n\nAntonyms:\n1) table\n2) seat\n3) lamp"
    qs = make(server, tmp_path).expand("chair")
    assert qs.positives == ["chair", "seat", "stool"] and qs.negatives == ["table", "lamp"]


def test_cache_and_offline(server, tmp_path):
    h = make(server, tmp_path)
    first = h.expand("chair")
    assert h.cache_path("chair").exists()
    again = make(server, tmp_path).expand("chair")
    assert len(server.requests) == 1  # served from cache
    assert again.positives == first.positives and again.negatives == first.negatives
    assert again.provenance["source"] == "cache"
    server.close()
    offline = make(server, tmp_path, offline=True)
    qs = offline.expand("chair")
    assert qs.positives == first.positives
    with pytest.raises(HeuristicError, match="offline.*'table'"):
        offline.expand("table")
    # a different model or prompt count is a different key
    with pytest.raises(HeuristicError, match="offline"):
        make(server, tmp_path, offline=True, model="other-model").expand("chair")
    with pytest.raises(HeuristicError, match="offline"):
        make(server, tmp_path, offline=True, n_synonyms=5).expand("chair")
    server.httpd = _Dummy()  # already closed


def test_llm_cache_folder_is_private(server, tmp_path):
    """The cached query sets name every query asked: their folder is 0700 whatever the
    umask (it was 0777 under umask 0)."""
    import os
    import stat

    old = os.umask(0)
    try:
        h = make(server, tmp_path, cache_dir=str(tmp_path / "a" / "llm"))
        h.expand("chair")
    finally:
        os.umask(old)
    for folder in (tmp_path / "a", tmp_path / "a" / "llm"):
        assert stat.S_IMODE(folder.stat().st_mode) == 0o700, folder
    assert h.cache_path("chair").exists()


def test_a_sampled_reply_is_cached_per_temperature_and_seed(server, tmp_path):
    from quash_plugins.core.interfaces import ExpansionContext

    # greedy decoding (temperature 0): the seed changes nothing, one cached set serves all
    greedy = make(server, tmp_path)
    greedy.expand("chair", ExpansionContext(seed=1))
    make(server, tmp_path).expand("chair", ExpansionContext(seed=2))
    make(server, tmp_path, json_mode=True).expand("chair")
    assert len(server.requests) == 1
    assert "temperature" not in greedy.cache_key("chair", 1)  # the key caches always had
    # sampling: another temperature or another seed is another reply, asked for again
    hot = make(server, tmp_path, temperature=0.7)
    hot.expand("chair", ExpansionContext(seed=1))
    assert len(server.requests) == 2 and server.requests[-1]["body"]["seed"] == 1
    make(server, tmp_path, temperature=0.7).expand("chair", ExpansionContext(seed=1))
    assert len(server.requests) == 2  # the same temperature and seed: served from cache
    make(server, tmp_path, temperature=0.7).expand("chair", ExpansionContext(seed=2))
    make(server, tmp_path, temperature=0.9).expand("chair", ExpansionContext(seed=1))
    assert len(server.requests) == 4
    assert hot.cache_path("chair", 1) != hot.cache_path("chair", 2) != greedy.cache_path("chair")
    with pytest.raises(HeuristicError, match=r"offline.*temperature 0.7, seed 3\)"):
        make(server, tmp_path, temperature=0.7, offline=True).expand(
            "chair", ExpansionContext(seed=3)
        )


class _Dummy:
    def shutdown(self):
        pass

    def server_close(self):
        pass


def test_server_down_is_clear(tmp_path):
    s = ChatServer()
    url = s.base_url
    s.close()
    h = registry.create(
        "heuristics",
        "llm",
        model="m",
        base_url=url,
        timeout=0.5,
        max_retries=1,
        backoff=0.01,
        cache_dir=str(tmp_path / "c"),
    )
    with pytest.raises(HeuristicError) as err:
        h.expand("chair")
    msg = str(err.value)
    # the URL, what happened and the fix (was: "connection failed (ConnectError)" and
    # "check that the server is running")
    host = url.split("/")[2]
    assert f"connection refused (nothing listens on {host})" in msg and url in msg
    assert "Start the server (Ollama: ollama serve" in msg and "set base_url" in msg
    assert "offline: true" in msg


def test_default_cache_dir_honours_env(server, tmp_path):
    h = make(server, tmp_path, cache_dir=None)
    h.expand("chair")
    assert h.cache_path("chair").parent == tmp_path / "quash-cache" / "llm"
    assert h.cache_path("chair").exists()


def test_api_key_sent_but_never_stored(server, tmp_path, monkeypatch, caplog):
    monkeypatch.setenv("MY_LLM_KEY", SECRET)
    caplog.set_level(logging.DEBUG)
    h = make(server, tmp_path, api_key_env="MY_LLM_KEY")
    qs = h.expand("chair")
    assert server.requests[0]["headers"]["Authorization"] == f"Bearer {SECRET}"
    for f in (tmp_path / "llm").rglob("*"):
        if f.is_file():
            assert SECRET not in f.read_text()
    assert SECRET not in json.dumps(qs.to_dict())
    assert SECRET not in qs.to_yaml()
    assert SECRET not in caplog.text
    assert SECRET not in repr(vars(h))


def test_missing_key_env_is_clear(server, tmp_path, monkeypatch):
    monkeypatch.delenv("NO_SUCH_KEY_VAR", raising=False)
    with pytest.raises(HeuristicError, match="NO_SUCH_KEY_VAR"):
        make(server, tmp_path, api_key_env="NO_SUCH_KEY_VAR").expand("chair")
    assert not server.requests


def test_config_errors():
    with pytest.raises(ConfigError, match="model"):
        LLMHeuristic()
    with pytest.raises(ConfigError, match="base_url"):
        LLMHeuristic(model="m", base_url="localhost:8000")


def test_endpoint_forms():
    assert chat_endpoint("http://h:1/v1/") == "http://h:1/v1/chat/completions"
    assert chat_endpoint("http://h:1/v1/chat/completions") == "http://h:1/v1/chat/completions"
    # credentials and query strings never reach cache keys or provenance
    assert chat_endpoint("https://user:pw@h/v1?key=x") == "https://h/v1/chat/completions"


def test_conformance_kit(server, tmp_path):
    from quash_plugins.testing import check_heuristic

    check_heuristic(make(server, tmp_path), tmp_path)


def test_quash_expand_cli(server, tmp_path, capsys):
    from quash_plugins.cli.main import main

    cfg = tmp_path / "llm.yaml"
    cfg.write_text(
        "encoder: {name: table, table: {chair: [1, 0], other: [0, 1]}}\n"
        f"heuristic: {{name: llm, model: test-model, base_url: '{server.base_url}', "
        "cache_dir: llm-cache, backoff: 0.01}\n"
    )
    assert main(["expand", "chair", "-c", str(cfg), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["positives"][:2] == ["chair", "seat"]
    assert (tmp_path / "llm-cache").is_dir()  # relative cache_dir resolved against the config
    server.close()
    server.httpd = _Dummy()
    offline = tmp_path / "offline.yaml"
    offline.write_text(cfg.read_text().replace("backoff: 0.01", "offline: true"))
    assert main(["expand", "chair", "-c", str(offline)]) == 0
    out = capsys.readouterr().out
    assert "seat" in out and "from cache" in out
    assert main(["expand", "sofa", "-c", str(offline)]) == 1
    assert "no cached query set for 'sofa'" in capsys.readouterr().err


def test_items_in_any_script_are_kept(server, tmp_path):
    """A reply in Russian, Chinese or Japanese keeps its words (every non-Latin item was
    dropped: an item needed an ASCII letter or digit); curly and CJK quotes and full-width
    punctuation are stripped like ASCII ones."""
    server.default = json.dumps(
        {
            "synonyms": ["Стул", "кресло", "椅子", "スツール。", "“seat”", "Sessel"],
            "antonyms": ["стол", "桌子", "「ランプ」", "---", "Tisch"],
        }
    )
    qs = make(server, tmp_path).expand("стул")
    assert qs.positives == ["стул", "кресло", "椅子", "スツール", "seat", "sessel"]
    assert qs.negatives == ["стол", "桌子", "ランプ", "tisch"]


def test_full_width_separators_split_a_list(server, tmp_path):
    server.default = '{"synonyms": "椅子，凳子、座位", "antonyms": "桌子；灯"}'
    qs = make(server, tmp_path).expand("chair")
    assert qs.positives == ["chair", "椅子", "凳子", "座位"] and qs.negatives == ["桌子", "灯"]


def test_unknown_host_is_named():
    import httpx

    from quash_plugins.heuristics._llm_http import connect_reason

    exc = httpx.ConnectError("[Errno -2] Name or service not known")
    assert connect_reason(exc, "http://gpu-box.lan:8000/v1/chat/completions") == (
        "connection failed (host 'gpu-box.lan' not found)"
    )
    other = httpx.RemoteProtocolError("Server disconnected without sending a response.")
    assert connect_reason(other, "http://h/v1/chat/completions") == (
        "connection failed (RemoteProtocolError: Server disconnected without sending a response.)"
    )


def test_exhausted_retries_show_the_servers_words_and_the_fix(server, tmp_path):
    """A retried status carries the server's own message; the closing hint fits the last
    failure (was: the bare status and "check that the server is running" for all)."""
    for _ in range(2):
        server.play(500, raw=b'{"error": "CUDA out of memory"}')
    with pytest.raises(HeuristicError) as err:
        make(server, tmp_path, max_retries=1).expand("chair")
    msg = str(err.value)
    assert 'last: status 500: \'{"error": "CUDA out of memory"}\'' in msg
    assert "The server failed: see its log" in msg
    for _ in range(2):
        server.play(429, raw=b'{"error": {"message": "Rate limit reached"}}')
    with pytest.raises(HeuristicError) as err:
        make(server, tmp_path, max_retries=1).expand("chair")
    assert "Rate limit reached" in str(err.value) and "rate-limiting" in str(err.value)
    server.play(delay=0.6)
    server.play(delay=0.6)
    with pytest.raises(HeuristicError) as err:
        make(server, tmp_path, timeout=0.2, max_retries=1).expand("chair")
    assert "timed out after 0.2 s" in str(err.value)
    assert "raise timeout (now 0.2 s)" in str(err.value)


def test_prose_reply_suggests_json_mode(server, tmp_path):
    server.default = "A chair is something you sit on; people also sit on stools and benches."
    with pytest.raises(HeuristicError) as err:
        make(server, tmp_path, max_retries=0).expand("chair")
    assert "unusable reply" in str(err.value) and "set json_mode: true" in str(err.value)


def test_empty_content_says_the_model_ran_out_of_tokens(server, tmp_path):
    body = {
        "choices": [{"message": {"role": "assistant", "content": None}, "finish_reason": "length"}]
    }
    server.play(raw=json.dumps(body).encode())
    with pytest.raises(HeuristicError) as err:
        make(server, tmp_path, max_retries=0).expand("chair")
    assert "message content is empty (finish_reason 'length': the model ran out of tokens)" in str(
        err.value
    )


def test_json_mode_refused_by_the_server_says_to_turn_it_off(server, tmp_path):
    server.play(400, raw=b'{"error": {"message": "response_format is not supported"}}')
    with pytest.raises(HeuristicError) as err:
        make(server, tmp_path, json_mode=True).expand("chair")
    assert "response_format is not supported" in str(err.value)
    assert "set json_mode: false" in str(err.value) and len(server.requests) == 1


def test_a_key_with_a_trailing_newline_is_sent_stripped(server, tmp_path, monkeypatch):
    monkeypatch.setenv("MY_LLM_KEY", SECRET + "\n")
    make(server, tmp_path, api_key_env="MY_LLM_KEY").expand("chair")
    assert server.requests[0]["headers"]["Authorization"] == f"Bearer {SECRET}"


@pytest.mark.parametrize(
    ("value", "what"),
    [
        (f"\u201c{SECRET}\u201d", "U+201C at position 1"),
        (f"{SECRET[:9]} {SECRET[9:]}", "white space"),
    ],
)
def test_a_key_no_header_can_carry_is_refused_unshown(server, tmp_path, monkeypatch, value, what):
    """A key pasted with curly quotes or a space inside: one clear error that never shows
    the key and sends nothing (was: "unexpected error: UnicodeEncodeError", or five
    attempts ending in "connection failed (LocalProtocolError)")."""
    monkeypatch.setenv("MY_LLM_KEY", value)
    with pytest.raises(HeuristicError) as err:
        make(server, tmp_path, api_key_env="MY_LLM_KEY").expand("chair")
    msg = str(err.value)
    assert "'MY_LLM_KEY'" in msg and what in msg and "Copy the key again" in msg
    assert SECRET not in msg and SECRET[:9] not in msg and SECRET[9:] not in msg
    assert not server.requests


def test_an_empty_key_variable_says_empty(server, tmp_path, monkeypatch):
    monkeypatch.setenv("MY_LLM_KEY", "  ")
    with pytest.raises(HeuristicError, match="'MY_LLM_KEY' \\(api_key_env\\) is empty"):
        make(server, tmp_path, api_key_env="MY_LLM_KEY").expand("chair")
    assert not server.requests


def test_quash_cache_shows_and_clears_the_llm_query_sets(server, tmp_path, capsys, monkeypatch):
    """The second run asks no server; `quash cache info` lists the LLM query sets,
    `quash cache clear` keeps them (and says so), `quash cache clear --llm` deletes them
    and the next run asks again (the cache command knew only text embeddings: the LLM
    sets could be found only through provenance and deleted only by hand)."""
    from quash_plugins.cli.main import main

    monkeypatch.setenv("COLUMNS", "400")  # one line each
    cfg = tmp_path / "llm.yaml"
    cfg.write_text(
        "encoder: {name: table, table: {chair: [1, 0], other: [0, 1]}}\n"
        f"heuristic: {{name: llm, model: test-model, base_url: '{server.base_url}', "
        "backoff: 0.01}\n"
    )
    root = tmp_path / "quash-cache" / "llm"  # $QUASH_CACHE_DIR/llm (the autouse fixture)
    root.mkdir(parents=True)
    keep = tmp_path / "elsewhere.json"
    keep.write_text("{}")
    (root / ("0" * 32 + ".json")).symlink_to(keep)  # a planted link is never followed
    (root / "notes.txt").write_text("mine")  # nor anything not named like a query set
    for query in ("chair", "sofa", "chair"):
        assert main(["expand", query, "-c", str(cfg)]) == 0
    assert len(server.requests) == 2
    capsys.readouterr()
    assert main(["cache", "info"]) == 0
    out = capsys.readouterr().out
    assert f"LLM query sets: {root}: 2" in out
    assert f"test-model at {server.base_url}/chat/completions: 2" in out
    assert main(["cache", "info", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["llm"]["sets"] == 2
    assert main(["cache", "clear"]) == 0
    assert "kept 2 LLM query sets" in capsys.readouterr().out
    assert main(["cache", "clear", "--llm"]) == 0
    assert f"cleared 2 LLM query sets from {root}" in capsys.readouterr().out
    assert keep.read_text() == "{}" and (root / "notes.txt").exists()
    assert (root / ("0" * 32 + ".json")).is_symlink()
    assert main(["expand", "chair", "-c", str(cfg)]) == 0
    assert len(server.requests) == 3  # asked again
    # a config's own cache_dir: --dir with --llm
    own = tmp_path / "own"
    cfg.write_text(cfg.read_text().replace("backoff: 0.01", "backoff: 0.01, cache_dir: own"))
    assert main(["expand", "table", "-c", str(cfg)]) == 0
    capsys.readouterr()
    assert main(["cache", "info", "--llm", "--dir", str(own)]) == 0
    assert f"LLM query sets: {own}: 1" in capsys.readouterr().out
    assert main(["cache", "clear", "--llm", "--dir", str(own)]) == 0
    assert not list(own.glob("*.json"))
    assert main(["cache", "clear", "--llm", "--fingerprint", "x"]) == 2


def test_quash_expand_needs_no_encoder_weights_for_the_llm(server, tmp_path, capsys):
    """`quash expand` with an llm config whose encoder's weights are not on the machine
    shows the LLM's set, with a warning (it stopped at the encoder: a user checking the
    LLM first had to fetch the OpenCLIP weights); a heuristic that embeds still stops
    with the encoder's error, and `quash query` too."""
    from quash_plugins.cli.main import main

    missing = tmp_path / "no-such-ViT-B-32.pt"
    cfg = tmp_path / "llm.yaml"
    cfg.write_text(
        f"encoder: {{name: open-clip, preset: lseg, checkpoint: '{missing}'}}\n"
        f"heuristic: {{name: llm, model: test-model, base_url: '{server.base_url}', "
        "backoff: 0.01}\n"
    )
    assert main(["expand", "chair", "-c", str(cfg), "--json"]) == 0
    captured = capsys.readouterr()
    assert json.loads(captured.out)["positives"][:2] == ["chair", "seat"]
    err = " ".join(captured.err.split())
    assert "does not exist" in err and "going on without the encoder" in err
    vocab = tmp_path / "vocabulary.yaml"
    vocab.write_text(cfg.read_text().split("heuristic")[0] + "heuristic: vocabulary\n")
    assert main(["expand", "chair", "-c", str(vocab)]) == 1
    assert "does not exist" in capsys.readouterr().err
    lmap = tmp_path / "map.npz"
    np.savez(lmap, embeddings=np.eye(4, 512, dtype=np.float32))
    assert main(["query", str(lmap), "chair", "-c", str(cfg)]) == 1
    assert "does not exist" in capsys.readouterr().err
    # a misspelt encoder name is a typo, not weights missing here: an error, as in query
    typo = tmp_path / "typo.yaml"
    typo.write_text(cfg.read_text().replace("name: open-clip", "name: openclip"))
    assert main(["expand", "chair", "-c", str(typo)]) == 1
    err = " ".join(capsys.readouterr().err.split())
    assert "Did you mean 'open-clip'" in err and "going on without" not in err
    # a name like no registered encoder may be a plugin this machine lacks: put off
    other = tmp_path / "other.yaml"
    other.write_text(cfg.read_text().replace("name: open-clip, preset: lseg, ", "name: lseg-x, "))
    assert main(["expand", "chair", "-c", str(other)]) == 0
    assert "going on without the encoder" in " ".join(capsys.readouterr().err.split())


def _llm_chair_map(server, tmp_path, extra: str = "", key_env: str = ""):
    """A three-item map and an llm config on ``server`` whose table encoder puts the
    server's chair synonyms on one axis and its antonyms on the other."""
    table = {w: [1.0, 0.0] for w in ("chair", "seat", "armchair", "stool")}
    table.update({w: [0.0, 1.0] for w in ("table", "lamp", "rug", "other", "background")})
    table["nothing"] = [0.0, 1.0]
    key = f"api_key_env: {key_env}, " if key_env else ""
    cfg = tmp_path / "llm.yaml"
    cfg.write_text(
        f"encoder: {{name: table, table: {json.dumps(table)}}}\n"
        f"heuristic: {{name: llm, model: test-model, base_url: '{server.base_url}', "
        f"{key}backoff: 0.01}}\nrefine: null\npresence: null\n{extra}"
    )
    lmap = tmp_path / "map.npz"
    np.savez(lmap, embeddings=np.array([[1, 0], [0, 1], [1, 0.1]], dtype=np.float32))
    return lmap, cfg


def test_verbose_query_lists_the_llms_synonyms_and_antonyms(server, tmp_path, capsys):
    """`quash -v query` shows what the LLM said for each query (was: only the counts in
    the table), and whether the set came from the server or the cache."""
    from quash_plugins.cli.main import main

    lmap, cfg = _llm_chair_map(server, tmp_path, "instances: false\n")
    for source in ("server", "cache"):
        assert main(["-v", "query", str(lmap), "chair", "-c", str(cfg)]) == 0
        err = " ".join(capsys.readouterr().err.split())
        assert (
            f"query set for 'chair': llm from {source}; 4 positives: chair, seat, armchair, "
            "stool; 6 negatives: table, lamp, rug, other, background, nothing"
        ) in err
    assert len(server.requests) == 1


def test_out_npz_records_the_llm_model_endpoint_and_source(server, tmp_path, monkeypatch):
    """The --out NPZ says which model at which endpoint gave each query set, and whether
    it came from the server or the cache (it said only 'llm'); never the key."""
    from quash_plugins.cli.main import main

    monkeypatch.setenv("MY_LLM_KEY", SECRET)
    lmap, cfg = _llm_chair_map(server, tmp_path, key_env="MY_LLM_KEY")
    for source in ("server", "cache"):
        out = tmp_path / f"{source}.npz"
        assert main(["query", str(lmap), "chair", "-c", str(cfg), "--out", str(out)]) == 0
        with np.load(out) as z:
            text = str(z["provenance"])
        record = json.loads(text)["queries"][0]
        assert record["heuristic"] == "llm" and record["source"] == source
        params = record["heuristic_params"]
        assert params["model"] == "test-model"
        assert params["endpoint"] == f"{server.base_url}/chat/completions"
        assert params["api_key_env"] == "MY_LLM_KEY" and SECRET not in text


@pytest.mark.parametrize(
    ("edit", "served"),
    [
        ({"synonyms": "seat"}, None),  # was: positives chair, s, e, a, t
        ({"synonyms": None}, None),  # was: unexpected error: KeyError ('synonyms' removed)
        ({"antonyms": ["table", 5]}, None),
        ({"synonyms": ["Seat ", "seat", "CHAIR", "stool"]}, ["chair", "seat", "stool"]),
    ],
)
def test_a_damaged_or_hand_edited_cache_file(server, tmp_path, edit, served):
    """A cache file whose lists are not lists of strings is ignored with a warning (and
    asked again); one edited by hand is cleaned as a reply is."""
    h = make(server, tmp_path)
    h.expand("chair")
    path = h.cache_path("chair")
    data = json.loads(path.read_text())
    data.update(edit)
    data = {k: v for k, v in data.items() if v is not None}
    path.write_text(json.dumps(data))
    qs = make(server, tmp_path).expand("chair")
    if served is None:
        assert qs.provenance["source"] == "server" and len(server.requests) == 2
        assert qs.positives == ["chair", "seat", "armchair", "stool"]
    else:
        assert qs.provenance["source"] == "cache" and qs.positives == served
    path.write_text("[1, 2]")  # not an object: asked again (was: AttributeError)
    assert make(server, tmp_path).expand("chair").provenance["source"] == "server"


def test_401_without_api_key_env_says_to_set_it(server, tmp_path, monkeypatch):
    """A hosted API asked without a key: the hint says to set api_key_env (it said to
    check the key in api_key_env, which was not set); with one, it names the variable."""
    server.play(401, raw=b'{"error": {"message": "You didn\'t provide an API key."}}')
    with pytest.raises(HeuristicError) as err:
        make(server, tmp_path).expand("chair")
    assert "set api_key_env to the name of the environment variable" in str(err.value)
    assert "Authorization" not in server.requests[0]["headers"]
    monkeypatch.setenv("MY_LLM_KEY", SECRET)
    server.play(401, raw=b'{"error": {"message": "Incorrect API key provided"}}')
    with pytest.raises(HeuristicError, match="Check the API key in 'MY_LLM_KEY'"):
        make(server, tmp_path, api_key_env="MY_LLM_KEY").expand("chair")
