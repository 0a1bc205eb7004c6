"""The API key never reaches an error, a log line, the terminal or a cache file.

A real HTTP server on 127.0.0.1 echoes the key it receives, as hosted APIs do
("Incorrect API key provided: sk-..."); the client talks to it with httpx.
"""

from __future__ import annotations

import json
import logging
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import pytest

from quash_plugins.core import registry
from quash_plugins.core.errors import ConfigError, HeuristicError
from quash_plugins.core.redact import redact

pytest.importorskip("httpx")

KEY = "sk-proj-Zx9vQ2mT7rK4pL8sW1nB6yH3"
PLAIN_KEY = "plainsecretvalue9876"  # a key that looks like nothing in particular
SHORT_KEY = "Qz9x"  # a local server's short key: was shown, cached and queried as a word
REGEX_KEY = "s3cr.t*K(y)+[9]$^|?"  # regular-expression metacharacters


class EchoServer:
    """Answers every request with ``mode``; the body echoes the Authorization header."""

    def __init__(self) -> None:
        self.mode = "401"
        self.requests: list[dict] = []
        outer = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args):
                pass

            def do_POST(self):  # noqa: N802 - http.server API
                self.rfile.read(int(self.headers.get("Content-Length", 0)))
                auth = self.headers.get("Authorization", "")
                outer.requests.append({"auth": auth, "path": self.path})
                key = auth.removeprefix("Bearer ")
                if outer.mode == "401":
                    status = 401
                    body = json.dumps(
                        {"error": {"message": f"Incorrect API key provided: {key}. ({auth})"}}
                    )
                elif outer.mode == "garbage":
                    status, body = 200, f"<html>upstream said {auth}</html>"
                else:  # a reply whose lists carry the key
                    content = json.dumps({"synonyms": ["seat", key], "antonyms": ["table", auth]})
                    status = 200
                    body = json.dumps({"choices": [{"message": {"content": content}}]})
                data = body.encode()
                self.send_response(status)
                self.send_header("Content-Type", "application/json")
                self.send_header("Content-Length", str(len(data)))
                self.end_headers()
                self.wfile.write(data)

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.httpd.daemon_threads = True
        threading.Thread(target=self.httpd.serve_forever, daemon=True).start()
        self.port = self.httpd.server_address[1]
        self.base_url = f"http://127.0.0.1:{self.port}/v1"

    def close(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()


@pytest.fixture
def echo():
    s = EchoServer()
    yield s
    s.close()


def _files_text(folder) -> str:
    return "".join(p.read_text() for p in folder.rglob("*") if p.is_file())


def _make(echo, tmp_path, **kw):
    params = dict(
        model="m",
        base_url=echo.base_url,
        api_key_env="QUASH_TEST_KEY",
        max_retries=1,
        backoff=0.01,
        timeout=5.0,
        cache_dir=str(tmp_path / "llm"),
    )
    params.update(kw)
    return registry.create("heuristics", "llm", **params)


@pytest.mark.parametrize("key", [KEY, PLAIN_KEY, SHORT_KEY, REGEX_KEY])
def test_401_echoing_the_key_is_redacted(echo, tmp_path, monkeypatch, caplog, key):
    monkeypatch.setenv("QUASH_TEST_KEY", key)
    caplog.set_level(logging.DEBUG)
    with pytest.raises(HeuristicError) as info:
        _make(echo, tmp_path).expand("chair")
    assert echo.requests[0]["auth"] == f"Bearer {key}"  # the key was sent...
    message = str(info.value)
    assert "status 401" in message and "Incorrect API key provided: ***" in message
    assert key not in message and key[:12] not in message  # ...and never shown
    assert key not in caplog.text


def test_cli_never_prints_the_key(echo, tmp_path, monkeypatch, capsys):
    from quash_plugins.cli.main import main

    monkeypatch.setenv("QUASH_TEST_KEY", KEY)
    cfg = tmp_path / "llm.yaml"
    cfg.write_text(
        "encoder: {name: table, table: {chair: [1, 0], other: [0, 1]}}\n"
        f"heuristic: {{name: llm, model: m, base_url: '{echo.base_url}', "
        "api_key_env: QUASH_TEST_KEY, backoff: 0.01, max_retries: 1, cache_dir: c}\n"
    )
    for mode in ("401", "garbage"):
        echo.mode = mode
        assert main(["-v", "expand", "chair", "-c", str(cfg)]) == 1
        captured = capsys.readouterr()
        assert KEY not in captured.err + captured.out
        assert "***" in captured.err
    assert not (tmp_path / "c").exists() or KEY not in _files_text(tmp_path / "c")


@pytest.mark.parametrize("key", [KEY, SHORT_KEY, REGEX_KEY])
def test_a_reply_carrying_the_key_never_reaches_the_cache_or_the_query_set(
    echo, tmp_path, monkeypatch, key
):
    monkeypatch.setenv("QUASH_TEST_KEY", key)
    echo.mode = "reply"
    qs = _make(echo, tmp_path).expand("chair")
    assert qs.positives == ["chair", "seat"] and qs.negatives == ["table"]
    cached = _files_text(tmp_path / "llm")
    assert key not in cached and key.lower() not in cached


def test_credentials_in_base_url_are_never_sent_shown_or_cached(echo, tmp_path, caplog):
    caplog.set_level(logging.DEBUG)
    url = f"http://robot:{KEY}@127.0.0.1:{echo.port}/v1"
    echo.mode = "401"
    h = _make(echo, tmp_path, base_url=url, api_key_env=None)
    assert KEY not in repr(vars(h)) and KEY not in json.dumps(h.params())
    with pytest.raises(HeuristicError) as info:
        h.expand("chair")
    assert echo.requests[0]["auth"] == ""  # userinfo is not turned into Basic auth
    assert KEY not in str(info.value) and KEY not in caplog.text
    assert "carries credentials" in caplog.text
    with pytest.raises(ConfigError) as bad:
        _make(echo, tmp_path, base_url=f"ftp://robot:{KEY}@127.0.0.1/v1")
    assert KEY not in str(bad.value)


def test_redact_patterns():
    assert redact(f"key {KEY} and Bearer abcdefgh1234 and api_key=zz99yy88") == (
        "key *** and Bearer *** and api_key=***"
    )
    assert redact("https://u:pw@host/v1") == "https://***@host/v1"
    assert redact("a desk-lamp, task-force, sk-8") == "a desk-lamp, task-force, sk-8"
    assert redact("value shortkey", ["abc"]) == "value shortkey"  # not a word of its own
    # a short key is removed where it stands as a word, metacharacters and all
    assert redact("key abc, (abc) abcd cabc", ["abc"]) == "key ***, (***) abcd cabc"
    assert redact("got +[9]: bad", ["+[9]"]) == "got ***: bad"
    assert redact("key a or ab", ["a", "ab"]) == "key a or ab"  # 1-2 characters: ignored
    assert redact(f"x{REGEX_KEY}y", [REGEX_KEY]) == "x***y"


def test_object_names_after_basic_or_bearer_are_not_credentials():
    """ "basic armchair" is an object, not HTTP Basic credentials: it was redacted to
    "basic ***" in every log line and error, and dropped from an LLM's lists."""
    for text in ("basic armchair", "a basic kitchen table", "ring bearer pillow"):
        assert redact(text) == text
    assert redact("Authorization: Basic dXNlcjpwYXNz") == "Authorization: Basic ***"
    assert redact("bearer abcdefgh-ijk and Bearer eyJhbGciOi") == "bearer *** and Bearer ***"


def test_an_llm_item_named_basic_is_kept(tmp_path, monkeypatch):
    from test_heuristics_llm import ChatServer

    server = ChatServer()
    try:
        server.default = json.dumps(
            {"synonyms": ["basic armchair", "seat"], "antonyms": ["ring bearer pillow"]}
        )
        h = registry.create(
            "heuristics", "llm", model="m", base_url=server.base_url, cache_dir=str(tmp_path)
        )
        qs = h.expand("chair")
    finally:
        server.close()
    assert qs.positives == ["chair", "basic armchair", "seat"]
    assert qs.negatives == ["ring bearer pillow"]
