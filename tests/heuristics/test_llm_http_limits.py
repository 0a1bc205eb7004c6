"""The ``llm`` heuristic's HTTP client against hostile or odd servers on 127.0.0.1: a key
echoed where a message is cut, credentials in base_url's query string, a key pasted into
api_key_env, a server that drips its reply, a body that is not what its Content-Encoding
says, replies of many megabytes, Retry-After as a date, a query string base_url needs, a
redirect, and a key sent over plain http to another host."""

from __future__ import annotations

import contextlib
import json
import logging
import socket
import threading
import time
from datetime import UTC, datetime, timedelta
from email.utils import format_datetime
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import pytest
from test_heuristics_llm import GOOD, ChatServer, _completion, make

from quash_plugins.core import registry
from quash_plugins.core.errors import ConfigError, HeuristicError
from quash_plugins.core.redact import redact, redact_start, redact_url
from quash_plugins.heuristics import _llm
from quash_plugins.heuristics._llm_http import MAX_REPLY_BYTES, retry_after
from quash_plugins.heuristics._parse import parse_reply

pytest.importorskip("httpx")

#: A key that looks like nothing in particular: only its exact value can redact it.
PLAIN_KEY = "plainsecretvalue9876abcdefghijkl"


class RawServer:
    """A server on 127.0.0.1 whose POST handler is ``handler(request_handler)``: it writes
    whatever it likes to the socket. ``sent`` counts the body bytes it managed to send."""

    def __init__(self, handler) -> None:
        self.sent = 0
        self.requests: list[str] = []
        self.stop = threading.Event()
        outer = self

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"

            def log_message(self, *args):
                pass

            def do_POST(self):  # noqa: N802 - http.server API
                self.rfile.read(int(self.headers.get("Content-Length", 0)))
                outer.requests.append(self.path)
                with contextlib.suppress(BrokenPipeError, ConnectionResetError):
                    handler(self, outer)
                self.close_connection = True

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.httpd.daemon_threads = True
        threading.Thread(target=self.httpd.serve_forever, daemon=True).start()
        self.base_url = f"http://127.0.0.1:{self.httpd.server_address[1]}/v1"

    def close(self) -> None:
        self.stop.set()
        self.httpd.shutdown()
        self.httpd.server_close()


def _make(base_url, tmp_path, **kw):
    params = dict(
        model="m", base_url=base_url, max_retries=0, backoff=0.01, timeout=5.0,
        cache_dir=str(tmp_path / "llm"),
    )  # fmt: skip
    params.update(kw)
    return registry.create("heuristics", "llm", **params)


# ------------------------------------------------------------------ 1. redact, then cut
def test_a_key_echoed_where_the_reply_is_cut_never_shows_in_part(
    server, tmp_path, monkeypatch, caplog
):
    """The model's prose echoed the key across the 120th character: the message was cut
    first and redacted after, so the cut key no longer matched and its first part showed
    in the warning and the error."""
    monkeypatch.setenv("MY_LLM_KEY", PLAIN_KEY)
    caplog.set_level(logging.DEBUG)
    server.default = "Sorry, I cannot list anything: the account " + "x" * 60 + " key " + PLAIN_KEY
    assert server.default.index(PLAIN_KEY) < 120 < server.default.index(PLAIN_KEY) + len(PLAIN_KEY)
    with pytest.raises(HeuristicError) as err:
        make(server, tmp_path, api_key_env="MY_LLM_KEY", max_retries=0).expand("chair")
    msg = str(err.value)
    assert "unusable reply" in msg
    for text in (msg, caplog.text):
        assert "plainsec" not in text
    assert "key ***" in msg


def test_parse_errors_redact_before_they_shorten():
    text = "x" * 110 + " " + PLAIN_KEY
    with pytest.raises(ValueError) as err:
        parse_reply(text, [PLAIN_KEY])
    assert "plainsec" not in str(err.value) and "***" in str(err.value)
    thoughts = "<think>" + "y" * 110 + " " + PLAIN_KEY
    with pytest.raises(ValueError) as err:
        parse_reply(thoughts, [PLAIN_KEY])
    assert "plainsec" not in str(err.value)
    assert redact_start("z" * 150 + PLAIN_KEY, [PLAIN_KEY], 160) == repr("z" * 150 + "***")


# ------------------------------------------------------------------ 2. query-string secrets
def test_query_string_secrets_in_base_url_are_never_shown(server, tmp_path, caplog):
    caplog.set_level(logging.DEBUG)
    port = server.base_url.split(":")[2].split("/")[0]
    url = (
        f"http://robot:Pw9Secret42@127.0.0.1:{port}/v1"
        "?key=QS7777secretval&code=Cd55secret&sig=Sg66secret&api-version=2024-02-01"
    )
    h = make(server, tmp_path, base_url=url)
    h.expand("chair")
    shown = caplog.text + h.base_url + json.dumps(h.params())
    assert "carries credentials" in caplog.text
    for secret in ("Pw9Secret42", "QS7777secretval", "Cd55secret", "Sg66secret"):
        assert secret not in shown
        assert secret not in h.cache_path("chair").read_text()
    assert "key=***" in caplog.text and "api-version=***" in caplog.text
    with pytest.raises(ConfigError) as bad:
        make(server, tmp_path, base_url="ftp://h/v1?token=Tk88secretval")
    assert "Tk88secretval" not in str(bad.value)


def test_redact_hides_credential_query_values_and_redact_url_all_of_them():
    assert redact("GET https://h/v1/x?sig=Abc123xyz&api-version=2024-02-01 failed") == (
        "GET https://h/v1/x?sig=***&api-version=2024-02-01 failed"
    )
    assert redact("https://h/?code=abcdef&access_token=zz9&url=rerun%2Bhttp") == (
        "https://h/?code=***&access_token=***&url=rerun%2Bhttp"
    )
    assert (
        redact_url("https://u:p@h/v1?a=1&b=&AIzaBare#frag") == "https://***@h/v1?a=***&b=&***#***"
    )


def test_redact_costs_linear_time():
    """The user-info pattern was tried at every word start and rescanned the rest of the
    text from each: 40 kB of "a." took seconds, 100 kB a minute."""
    t = time.monotonic()
    redact("a." * 10_000 + "sk-" * 5_000, ["abcdefgh"])  # took 6 s
    assert time.monotonic() - t < 1.0


# ------------------------------------------------------------------ 3. api_key_env
@pytest.mark.parametrize(
    "value", ["gsk_ZQX9secretkey7731abcdef", "sk-proj-Zx9vQ2mT7rK4pL8s", "my key", "9LIVES", 12345]
)
def test_a_key_pasted_into_api_key_env_is_refused_unshown(server, tmp_path, monkeypatch, value):
    monkeypatch.delenv(str(value), raising=False)
    with pytest.raises(ConfigError) as err:
        make(server, tmp_path, api_key_env=value)
    msg = str(err.value)
    assert "api_key_env must be the NAME of the environment variable" in msg
    assert str(value) not in msg and "ZQX9" not in msg
    assert not server.requests


def test_a_name_that_looks_random_is_taken_when_it_is_set(server, tmp_path, monkeypatch):
    monkeypatch.setenv("PROJ_A1B2C3D4E5F6G7H8I9", PLAIN_KEY)
    h = make(server, tmp_path, api_key_env="PROJ_A1B2C3D4E5F6G7H8I9")
    h.expand("chair")
    assert server.requests[0]["headers"]["Authorization"] == f"Bearer {PLAIN_KEY}"
    assert make(server, tmp_path, api_key_env="OPENAI_API_KEY").params()["api_key_env"] == (
        "OPENAI_API_KEY"
    )


# ------------------------------------------------------------------ 4. a whole-request deadline
def _drip_body(h, server):
    h.send_response(200)
    h.send_header("Content-Type", "application/json")
    h.send_header("Content-Length", "100000")
    h.end_headers()
    end = time.monotonic() + 6.0  # the test ends whatever the client does
    while time.monotonic() < end and not server.stop.is_set():
        h.wfile.write(b" ")
        h.wfile.flush()
        time.sleep(0.1)


def _drip_headers(h, server):
    h.wfile.write(b"HTTP/1.1 200 OK\r\n")
    end = time.monotonic() + 6.0
    while time.monotonic() < end and not server.stop.is_set():
        h.wfile.write(b"X-Slow: y\r\n")
        h.wfile.flush()
        time.sleep(0.1)


@pytest.mark.parametrize("drip", [_drip_body, _drip_headers])
def test_timeout_bounds_the_whole_request(raw, tmp_path, drip):
    """A server that sends a byte every 0.1 s never let a read time out: a run with
    timeout: 1 went on for as long as the server liked."""
    s = raw(drip)
    t = time.monotonic()
    with pytest.raises(HeuristicError) as err:
        _make(s.base_url, tmp_path, timeout=1.0).expand("chair")
    assert time.monotonic() - t < 3.0
    assert "timed out after 1 s" in str(err.value)


# ------------------------------------------------------------------ 5. Content-Encoding
def test_a_body_that_is_not_what_its_content_encoding_says(server, tmp_path):
    """Was: "unexpected error: DecodingError", naming no server."""
    server.play(raw=b"not gzip at all", headers={"Content-Encoding": "gzip"})
    qs = make(server, tmp_path).expand("chair")  # retried like other failed requests
    assert "seat" in qs.positives and len(server.requests) == 2
    for _ in range(2):
        server.play(raw=b"not gzip at all", headers={"Content-Encoding": "gzip"})
    h = make(server, tmp_path, max_retries=1, cache=False)
    with pytest.raises(HeuristicError) as err:
        h.expand("sofa")
    msg = str(err.value)
    assert h.endpoint in msg and "status 200 with a body that cannot be decoded" in msg
    assert "Content-Encoding 'gzip'" in msg and "compression settings" in msg


# ------------------------------------------------------------------ 6. size cap, linear parser
def test_a_reply_over_the_limit_is_refused_unread(server, tmp_path):
    padded = _completion(GOOD)[:-1] + b" " * (MAX_REPLY_BYTES + 10) + b"}"
    server.play(raw=padded)
    with pytest.raises(HeuristicError) as err:
        make(server, tmp_path, max_retries=0).expand("chair")
    assert "status 200 with a reply over 4 MiB" in str(err.value)


def test_a_streamed_reply_over_the_limit_is_cut_off(raw, tmp_path):
    """No Content-Length: the body is read as it streams, and reading stops at the limit
    (a 400 MB reply was read whole, 900 MB at the peak)."""
    total = 64 * 1024 * 1024

    def endless(h, server):
        h.send_response(200)
        h.send_header("Content-Type", "application/json")
        h.send_header("Connection", "close")
        h.end_headers()
        body = _completion(GOOD)
        h.wfile.write(body[:-1])
        chunk = b" " * (1024 * 1024)
        while server.sent < total:
            h.wfile.write(chunk)
            server.sent += len(chunk)
        h.wfile.write(b"}")

    s = raw(endless)
    with pytest.raises(HeuristicError, match="over 4 MiB"):
        _make(s.base_url, tmp_path, timeout=20.0).expand("chair")
    time.sleep(0.2)
    assert s.sent < total // 2


def test_a_body_nested_too_deep_is_not_json(server, tmp_path):
    """Was: "unexpected error: RecursionError"."""
    server.play(raw=b"[" * 200_000)
    with pytest.raises(HeuristicError, match="body is not JSON"):
        make(server, tmp_path, max_retries=0).expand("chair")


@pytest.mark.parametrize(
    "reply",
    [
        "{" * 25 + "a" * 2_000_000,  # took 11 s
        "<think>" * 10_000,  # took 7 s (300,000 of them: hours)
        '{"' * 1_000_000,  # 4 s
        "```" * 700_000,  # 2.7 s
        "[" * 2_000_000,  # RecursionError: "unexpected error"
        "Synonyms: " + "(" * 2_000_000,
    ],
)
def test_parsing_a_pathological_reply_is_fast(reply):
    t = time.monotonic()
    with contextlib.suppress(ValueError):
        parse_reply(reply)
    assert time.monotonic() - t < 1.5


def test_a_reply_with_a_million_items_is_cleaned_fast(server, tmp_path):
    server.default = json.dumps({"synonyms": ["seat"] * 150_000, "antonyms": ["table"] * 150_000})
    t = time.monotonic()
    qs = make(server, tmp_path).expand("chair")
    assert qs.positives == ["chair", "seat"] and qs.negatives == ["table"]
    assert time.monotonic() - t < 3.0


# ------------------------------------------------------------------ 7. Retry-After date
def test_retry_after_as_an_http_date_is_honoured(server, tmp_path):
    when = datetime.now(UTC) + timedelta(seconds=2.5)
    server.play(
        429,
        raw=b'{"error": "slow down"}',
        headers={"Retry-After": format_datetime(when, usegmt=True)},
    )
    qs = make(server, tmp_path, backoff=0.001).expand("chair")
    assert len(server.requests) == 2 and "seat" in qs.positives
    assert server.times[1] - server.times[0] >= 1.0


class _Resp:
    def __init__(self, value):
        self.headers = {} if value is None else {"retry-after": value}


def test_retry_after_forms():
    now = datetime(2025, 1, 1, 12, 0, 0, tzinfo=UTC)
    assert retry_after(_Resp("Wed, 01 Jan 2025 12:00:30 GMT"), now) == 30.0
    assert retry_after(_Resp("Wed, 01 Jan 2025 13:00:00 GMT"), now) == 60.0  # capped
    assert retry_after(_Resp("Wed, 01 Jan 2025 11:00:00 GMT"), now) == 0.0  # past
    assert retry_after(_Resp("Wed, 01 Jan 2025 12:00:10 -0000"), now) == 10.0
    assert retry_after(_Resp("7"), now) == 7.0
    assert retry_after(_Resp("600"), now) == 60.0
    for bad in (None, "", "soon", "nan", "-5"):
        assert retry_after(_Resp(bad), now) == 0.0


# ------------------------------------------------------------------ 8. the query string is sent
def test_base_urls_query_string_is_sent_but_never_recorded(server, tmp_path):
    h = make(server, tmp_path, base_url=server.base_url + "?api-version=2024-02-01")
    qs = h.expand("chair")
    assert server.requests[0]["path"] == "/v1/chat/completions?api-version=2024-02-01"
    assert h.endpoint == f"{server.base_url}/chat/completions"
    assert "api-version" not in json.dumps(qs.provenance, default=str)
    assert "api-version" not in h.cache_path("chair").read_text()
    server.play(404, raw=b"no such deployment")  # the models asked with it too
    with pytest.raises(HeuristicError):
        make(server, tmp_path, base_url=server.base_url + "/?api-version=2024-02-01").expand("sofa")
    assert server.gets[0] == "/v1/models?api-version=2024-02-01"


# ------------------------------------------------------------------ 9. redirects
def test_a_redirect_names_where_it_leads_and_is_not_followed(server, tmp_path, monkeypatch):
    monkeypatch.setenv("MY_LLM_KEY", PLAIN_KEY)
    where = "https://api.example.com/v1/chat/completions?sig=TopSecret77"
    server.play(302, raw=b"", headers={"Location": where})
    with pytest.raises(HeuristicError) as err:
        make(server, tmp_path, api_key_env="MY_LLM_KEY").expand("chair")
    msg = str(err.value)
    assert "answered status 302, a redirect" in msg
    assert "redirects to https://api.example.com/v1/chat/completions?sig=***" in msg
    assert "set base_url: https://api.example.com/v1?sig=***" in msg
    assert "TopSecret77" not in msg and len(server.requests) == 1
    server.play(308, raw=b"", headers={"Location": "/api/v1/chat/completions"})
    with pytest.raises(HeuristicError, match=r"set base_url: http://127\.0\.0\.1:\d+/api/v1\."):
        make(server, tmp_path).expand("chair")


# ------------------------------------------------------------------ 10. cleartext key
@pytest.fixture
def proxy_to(monkeypatch):
    """Route http:// requests through ``server`` as a forward proxy (offline: the remote
    host is never looked up)."""
    for name in ("HTTP_PROXY", "HTTPS_PROXY", "ALL_PROXY", "NO_PROXY"):
        monkeypatch.delenv(name, raising=False)
        monkeypatch.delenv(name.lower(), raising=False)
    monkeypatch.setattr(_llm, "_CLEARTEXT_WARNED", set())

    def route(server: ChatServer) -> None:
        monkeypatch.setenv("HTTP_PROXY", server.base_url.removesuffix("/v1"))

    return route


def test_a_key_sent_over_plain_http_to_another_host_is_warned_about_once(
    server, tmp_path, monkeypatch, caplog, proxy_to
):
    proxy_to(server)
    monkeypatch.setenv("MY_LLM_KEY", PLAIN_KEY)
    caplog.set_level(logging.WARNING)
    h = make(server, tmp_path, base_url="http://gpu-box.example:8000/v1", api_key_env="MY_LLM_KEY")
    h.expand("chair")
    h.expand("sofa")
    make(
        server, tmp_path, base_url="http://gpu-box.example:8000/v1", api_key_env="MY_LLM_KEY"
    ).expand("lamp")
    assert server.requests[0]["path"] == "http://gpu-box.example:8000/v1/chat/completions"
    warned = [r.getMessage() for r in caplog.records if "plain http" in r.getMessage()]
    assert len(warned) == 1
    assert "gpu-box.example" in warned[0] and "https://" in warned[0] and "MY_LLM_KEY" in warned[0]
    assert PLAIN_KEY not in caplog.text


def test_no_cleartext_warning_for_this_machine_or_without_a_key(
    server, tmp_path, monkeypatch, caplog, proxy_to
):
    monkeypatch.setenv("MY_LLM_KEY", PLAIN_KEY)
    caplog.set_level(logging.WARNING)
    make(server, tmp_path, api_key_env="MY_LLM_KEY").expand("chair")  # 127.0.0.1
    proxy_to(server)
    make(server, tmp_path, base_url="http://gpu-box.example:8000/v1").expand("chair")  # no key
    assert "plain http" not in caplog.text


def test_the_deadline_leaves_no_socket_open(server, tmp_path):
    """Each request's watched socket duplicates are closed (no ResourceWarning, no fd
    leak over many queries)."""
    import os

    fds = len(os.listdir("/proc/self/fd")) if os.path.isdir("/proc/self/fd") else None
    h = make(server, tmp_path, cache=False)
    for q in ("chair", "sofa", "lamp", "table", "rug"):
        h.expand(q)
    if fds is not None:
        assert len(os.listdir("/proc/self/fd")) <= fds + 2
    with socket.socket() as s:  # the loopback still serves
        s.connect(("127.0.0.1", int(server.base_url.split(":")[2].split("/")[0])))
