"""The ``llm`` heuristic's side of HTTP: the client, reading a chat-completions reply,
and saying in words what went wrong.

Everything that quotes a server's words passes them through :func:`redact` with the API
key first. A loopback endpoint (``127.0.0.1``, ``::1``, ``localhost``) is reached
directly, never through a proxy named by ``HTTP_PROXY``/``HTTPS_PROXY``/``ALL_PROXY``: a
proxy cannot reach this machine's loopback, so on a cluster that sets one a local Ollama
or vLLM would otherwise look down. Other hosts follow the environment (``NO_PROXY``
included), and a failure names the proxy it went through.

Every request is bounded (:func:`bounded_request`): ``timeout`` seconds for the whole of
it, from connecting to the last byte of the body (httpx's own time-outs bound each read,
so a server sending a byte every half second kept a request alive for ever), and at most
:data:`MAX_REPLY_BYTES` of body (a reply is streamed, never read whole).
"""

from __future__ import annotations

import contextlib
import email.utils
import ipaddress
import json
import socket
import threading
import time
import urllib.request
from collections.abc import Iterable
from datetime import UTC, datetime
from typing import Any
from urllib.parse import urljoin, urlsplit, urlunsplit

from ..core.errors import HeuristicError
from ..core.redact import redact, redact_start, redact_url

#: How many of the server's model names a 404 message lists.
MAX_MODELS_SHOWN = 12
#: The largest body read from the server, after decompression (4 MiB). A chat reply with
#: two lists of 20 words is a few kB; a larger body is refused with an error, unread.
MAX_REPLY_BYTES = 4 * 1024 * 1024
#: The longest wait a ``Retry-After`` header can ask for, in seconds.
MAX_RETRY_AFTER = 60.0
#: Redirect statuses: never followed (the Authorization header would go with them).
REDIRECT_STATUSES = frozenset({301, 302, 303, 307, 308})


class ReplyError(ValueError):
    """A status-200 reply the heuristic cannot use. ``kind``: ``"api"`` (the body is not a
    chat completion: base_url leads elsewhere), ``"length"`` (the model stopped at its
    token limit) or ``"reply"`` (the model's message holds no usable lists)."""

    def __init__(self, message: str, kind: str = "reply") -> None:
        super().__init__(message)
        self.kind = kind


def is_loopback(host: str | None) -> bool:
    """True for ``localhost`` and loopback addresses (``127.0.0.0/8``, ``::1``)."""
    if not host:
        return False
    host = host.strip("[]").lower()
    if host == "localhost" or host.endswith(".localhost"):
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def client_options(endpoint: str) -> dict[str, Any]:
    """Extra ``httpx.Client`` arguments for ``endpoint``: a loopback host is mounted on
    the direct transport, so no proxy from the environment is used for it."""
    host = urlsplit(endpoint).hostname
    if not is_loopback(host):
        return {}
    name = f"[{host}]" if ":" in str(host) else str(host)
    return {"mounts": {f"all://{name}": None}}


def env_proxy(endpoint: str) -> str | None:
    """The proxy the environment routes ``endpoint`` through (credentials redacted), or
    None: none set, ``NO_PROXY`` names the host, or the host is loopback."""
    parts = urlsplit(endpoint)
    if is_loopback(parts.hostname):
        return None
    proxies = urllib.request.getproxies()
    proxy = proxies.get(parts.scheme) or proxies.get("all")
    if not proxy:
        return None
    try:
        if urllib.request.proxy_bypass(parts.hostname or ""):
            return None
    except OSError:  # a platform lookup that fails: assume the proxy applies
        pass
    return redact(proxy)


def proxy_note(endpoint: str) -> str:
    """A sentence naming the environment's proxy for ``endpoint``, or ''."""
    proxy = env_proxy(endpoint)
    if proxy is None:
        return ""
    host = urlsplit(endpoint).hostname
    return (
        f" The request went through the proxy {proxy} named by the environment "
        f"(HTTP_PROXY/HTTPS_PROXY/ALL_PROXY); if {host} is reachable directly, add it to "
        "NO_PROXY."
    )


def check_key(key: str, env: str) -> str:
    """The key without surrounding white space; refused (never shown) when an HTTP header
    cannot carry it: white space or a character outside printable ASCII inside it."""
    key = key.strip()
    for i, ch in enumerate(key):
        if not ("!" <= ch <= "~"):
            what = "white space" if ch.isspace() else f"the character U+{ord(ch):04X}"
            raise HeuristicError(
                f"Heuristic 'llm': the API key in {env!r} (api_key_env) holds {what} at "
                f"position {i + 1}, which an HTTP header cannot carry. Copy the key again "
                "(a quote or a line break pasted with it?) and export it."
            )
    return key


def _secrets(key: str | Iterable[str]) -> list[str]:
    return [key] if isinstance(key, str) else list(key)


def tls_failure(exc: Any) -> str | None:
    """``"plain"`` when an https handshake met a server that speaks plain http (OpenSSL's
    "wrong version number": ``https://`` for a local vLLM, Ollama or llama.cpp),
    ``"cert"`` when the server's certificate is not trusted, else None."""
    low = str(exc).lower()
    if "wrong version number" in low or "wrong_version_number" in low:
        return "plain"
    if "certificate verify failed" in low or "certificate_verify_failed" in low:
        return "cert"
    return None


def connect_reason(exc: Any, endpoint: str, key: str | Iterable[str] = "") -> str:
    """Why a connection failed, in words: refused, an unknown host, or httpx's reason;
    through which proxy, when the environment names one for ``endpoint``. ``key``: the
    secrets (one, or several) to redact from httpx's words."""
    text = redact(str(exc), _secrets(key))
    parts = urlsplit(endpoint)
    low = text.lower()
    proxy = env_proxy(endpoint)
    if proxy is not None:
        return (
            f"connection failed through the proxy {proxy} from the environment "
            f"({type(exc).__name__}{': ' + text if text else ''})"
        )
    tls = tls_failure(exc)
    if tls == "plain":
        return f"TLS handshake failed: {parts.netloc} answers plain http, not https ({text})"
    if tls == "cert":
        return f"TLS handshake failed: the certificate of {parts.hostname} is not trusted ({text})"
    if "refused" in low:
        return f"connection refused (nothing listens on {parts.netloc})"
    unknown = ("name or service not known", "nodename nor servname", "name resolution")
    if any(w in low for w in unknown) or "getaddrinfo" in low:
        return f"connection failed (host {parts.hostname!r} not found)"
    return f"connection failed ({type(exc).__name__}{': ' + text if text else ''})"


def content_of(resp: Any, key: str | Iterable[str] = "") -> tuple[str, str | None]:
    """The assistant message of a chat-completions response and its ``finish_reason``
    (a message given as content parts, ``[{"type": "text", "text": ...}]``, joined);
    :class:`ReplyError` when the body is not a chat completion or holds no text. ``key``:
    the secrets (one, or several) to redact from the body quoted in the error."""
    secrets = _secrets(key)
    try:
        data = resp.json()
    except (ValueError, RecursionError):
        raise ReplyError(f"body is not JSON: {snippet(resp.text, secrets)}", "api") from None
    try:
        choice = data["choices"][0]
        content = choice["message"]["content"]
    except (KeyError, IndexError, TypeError):
        raise ReplyError(
            f"no choices[0].message.content in {snippet(resp.text, secrets)}", "api"
        ) from None
    finish = choice.get("finish_reason") if isinstance(choice, dict) else None
    if isinstance(content, list):  # content parts: [{"type": "text", "text": "..."}]
        texts = [p.get("text") for p in content if isinstance(p, dict)]
        if texts and all(isinstance(t, str) for t in texts):
            content = "".join(texts)
    if not isinstance(content, str):
        why = f"message content is {'empty' if content is None else type(content).__name__}"
        if finish == "length":
            raise ReplyError(
                why + " (finish_reason 'length': the model ran out of tokens)", "length"
            )
        if finish:
            why += f" (finish_reason {finish!r})"
        raise ReplyError(why)
    return content, finish if isinstance(finish, str) else None


def retry_after(resp: Any, now: datetime | None = None) -> float:
    """The wait a response's ``Retry-After`` header asks for, in seconds, at most
    :data:`MAX_RETRY_AFTER`: a number of seconds, or an HTTP date (``Wed, 21 Oct 2015
    07:28:00 GMT``); 0 when there is none or it cannot be read, or the date is past."""
    value = resp.headers.get("retry-after")
    if value is None or not value.strip():
        return 0.0
    value = value.strip()
    try:
        seconds = float(value)
    except ValueError:
        try:
            when = email.utils.parsedate_to_datetime(value)
        except (TypeError, ValueError, IndexError, OverflowError):
            return 0.0
        if when.tzinfo is None:  # "-0000" or no zone: HTTP dates are GMT
            when = when.replace(tzinfo=UTC)
        seconds = (when - (now or datetime.now(UTC))).total_seconds()
    if seconds != seconds:  # NaN
        return 0.0
    return min(max(0.0, seconds), MAX_RETRY_AFTER)


def snippet(text: str, secrets: Iterable[str] = (), n: int = 160) -> str:
    """The start of a server reply, credentials redacted before it is shortened."""
    return redact_start(text, secrets, n)


def redirect_hint(endpoint: str, location: str | None, secrets: Iterable[str] = ()) -> str:
    """What to do about a redirect from ``endpoint`` to ``location``: set base_url to where
    it leads (shown without credentials or query values). Redirects are never followed:
    the API key would go with them to wherever the server points."""
    why = (
        " Redirects are not followed, so that the API key and the query never go where "
        "base_url does not say."
    )
    if not location or not location.strip():
        return f" The server redirects without saying where (no Location header).{why}"
    target = urljoin(endpoint, location.strip())
    parts = urlsplit(target)
    shown = redact_url(target, secrets)
    if parts.scheme not in ("http", "https") or not parts.hostname:
        return f" The server redirects to {shown}.{why}"
    base = parts.path.rstrip("/").removesuffix("/chat/completions")
    suggest = redact_url(urlunsplit((parts.scheme, parts.netloc, base, parts.query, "")))
    return f" The server redirects to {shown}: if that is the API, set base_url: {suggest}.{why}"


def cleartext_host(endpoint: str) -> str | None:
    """The host of an ``http://`` endpoint that is not this machine (a key sent there
    crosses the network in cleartext), else None."""
    parts = urlsplit(endpoint)
    if parts.scheme != "http" or is_loopback(parts.hostname):
        return None
    return parts.hostname


class Reply:
    """A response read by :func:`bounded_request`: ``status_code``, ``headers``, the
    body's first :data:`MAX_REPLY_BYTES` (``content``), whether more was left unread
    (``truncated``) and the error that decoding its ``Content-Encoding`` raised, if any
    (``decode_error``)."""

    def __init__(
        self,
        status_code: int,
        headers: Any,
        content: bytes,
        encoding: str | None = None,
        truncated: bool = False,
        decode_error: str | None = None,
    ) -> None:
        self.status_code = status_code
        self.headers = headers
        self.content = content
        self.encoding = encoding
        self.truncated = truncated
        self.decode_error = decode_error

    @property
    def text(self) -> str:
        try:
            return self.content.decode(self.encoding or "utf-8", errors="replace")
        except LookupError:  # a charset Python does not know
            return self.content.decode("utf-8", errors="replace")

    def json(self) -> Any:
        """The body as JSON; ValueError when it is not (nesting too deep included)."""
        try:
            return json.loads(self.text)
        except RecursionError:
            raise ValueError("JSON nested too deep") from None


class _Deadline:
    """Ends a request at its deadline, wherever it waits: at the deadline, every socket
    the request connected (told by httpcore's ``trace`` extension) is shut down, which
    wakes a read blocked on it. A read that then fails is reported as the time-out."""

    def __init__(self, seconds: float) -> None:
        self.fired = False
        self._done = False
        self._lock = threading.Lock()
        self._socks: list[socket.socket] = []
        self._timer = threading.Timer(max(0.0, seconds), self._fire)
        self._timer.daemon = True
        self._timer.start()

    def trace(self, name: str, info: dict[str, Any]) -> None:
        """httpcore's trace callback: keep a duplicate of each socket it connects."""
        if not name.endswith("connect_tcp.complete"):
            return
        try:
            sock = info["return_value"].get_extra_info("socket")
            dup = sock.dup()
        except Exception:  # noqa: BLE001 - another backend: only httpx's time-outs apply
            return
        with self._lock:
            if self._done:
                dup.close()
                return
            self._socks.append(dup)
            if self.fired:
                self._shutdown(dup)

    @staticmethod
    def _shutdown(sock: socket.socket) -> None:
        with contextlib.suppress(OSError):
            sock.shutdown(socket.SHUT_RDWR)

    def _fire(self) -> None:
        with self._lock:
            if self._done:
                return
            self.fired = True
            for sock in self._socks:
                self._shutdown(sock)

    def close(self) -> None:
        self._timer.cancel()
        with self._lock:
            self._done = True
            for sock in self._socks:
                sock.close()
            self._socks.clear()


def bounded_request(
    client: Any,
    method: str,
    url: str,
    *,
    timeout: float,
    limit: int = MAX_REPLY_BYTES,
    **kwargs: Any,
) -> Reply:
    """``client.stream(method, url, **kwargs)`` read into a :class:`Reply`, within
    ``timeout`` seconds in all and at most ``limit`` bytes of (decoded) body.

    Raises httpx's ``ReadTimeout`` when the deadline passes (also while connecting,
    sending, or waiting for headers or for the body), and its other transport errors as
    they come. A body with more than ``limit`` bytes is cut there (``truncated``), the
    rest unread (a ``Content-Length`` over the limit: nothing read); one whose
    ``Content-Encoding`` cannot be decoded gives ``decode_error``.
    """
    import httpx

    deadline = time.monotonic() + timeout
    watch = _Deadline(timeout)
    extensions = {**kwargs.pop("extensions", {}), "trace": watch.trace}
    try:
        with client.stream(
            method, url, timeout=httpx.Timeout(timeout), extensions=extensions, **kwargs
        ) as resp:
            chunks: list[bytes] = []
            size, truncated, decode_error = 0, False, None
            declared = resp.headers.get("content-length", "").strip()
            if declared.isdigit() and int(declared) > limit:
                truncated = True
            else:
                try:
                    for chunk in resp.iter_bytes():
                        if time.monotonic() > deadline:
                            raise httpx.ReadTimeout(f"no whole reply within {timeout:g} s")
                        if size + len(chunk) > limit:
                            chunks.append(chunk[: limit - size])
                            truncated = True
                            break
                        size += len(chunk)
                        chunks.append(chunk)
                except httpx.DecodingError as exc:
                    decode_error = f"{type(exc).__name__}: {exc}"
            return Reply(
                resp.status_code,
                resp.headers,
                b"".join(chunks),
                resp.charset_encoding,
                truncated,
                decode_error,
            )
    except httpx.TransportError as exc:
        if watch.fired and not isinstance(exc, httpx.TimeoutException):
            raise httpx.ReadTimeout(f"no whole reply within {timeout:g} s") from None
        raise
    finally:
        watch.close()


def known_models(
    client: Any, endpoint: str, headers: dict[str, str], timeout: float = 5.0, query: str = ""
) -> tuple[str, list[str]]:
    """Ask the server which models it serves: ``GET .../models`` beside ``endpoint``, then
    at ``/v1/models`` of its origin (with base_url's ``query`` string, which an Azure-style
    API needs). Returns (the base URL that answered, the model ids); ``("", [])`` when
    neither does. Used only to explain a 404."""
    parts = urlsplit(endpoint)
    base = parts.path.removesuffix("/chat/completions")
    origin = (parts.scheme, parts.netloc)
    tried = []
    for path in (base, "/v1"):
        url = urlunsplit((*origin, path.rstrip("/") + "/models", query, ""))
        if url in tried:
            continue
        tried.append(url)
        try:
            resp = bounded_request(client, "GET", url, headers=headers, timeout=timeout)
            data = resp.json() if resp.status_code == 200 and not resp.truncated else None
        except Exception:  # noqa: BLE001 - only a hint: any failure means "unknown"
            continue
        rows = data.get("data") if isinstance(data, dict) else None
        if isinstance(rows, list):
            ids = [r["id"] for r in rows if isinstance(r, dict) and isinstance(r.get("id"), str)]
            if ids:
                return urlunsplit((*origin, path.rstrip("/"), "", "")), ids
    return "", []


def not_found_hint(endpoint: str, model: str, base: str, models: list[str]) -> str:
    """What to do about a 404 from ``endpoint``, given what :func:`known_models` found."""
    ours = urlsplit(endpoint).path.removesuffix("/chat/completions").rstrip("/")
    if models and base and urlsplit(base).path.rstrip("/") != ours:
        return (
            f" The API is at {base}, not under {ours or '/'}: set base_url: {base} "
            f"(the server serves {_names(models)})."
        )
    if models and model not in models:
        pull = f" (Ollama: ollama pull {model})" if ":" in model else ""
        return (
            f" The server does not serve model {model!r}; it serves {_names(models)}. "
            f"Set model to one of them, or load {model!r} on the server{pull}."
        )
    if "v1" not in ours.split("/"):
        parts = urlsplit(endpoint)
        guess = urlunsplit((parts.scheme, parts.netloc, ours + "/v1", "", ""))
        return (
            " Check base_url: OpenAI-compatible servers answer under /v1 "
            f"(base_url: {guess}?) and the model name."
        )
    return " Check base_url (it usually ends in /v1) and the model name."


def _names(models: list[str]) -> str:
    shown = ", ".join(repr(m) for m in models[:MAX_MODELS_SHOWN])
    more = len(models) - MAX_MODELS_SHOWN
    return shown + (f" and {more} more" if more > 0 else "")


def failure_fix(why: str, timeout: float, json_mode: bool, base_url: str) -> str:
    """What to do about the last failure of a chat request, by its kind ``why``
    (``"connect"``, ``"timeout"``, ``"rate"``...): the closing sentence of the
    ``llm`` heuristic's error. ``base_url`` is shown as it is: pass it redacted."""
    cached = "or use offline: true with a cache that holds the query sets."
    if why == "connect":
        return (
            f"Start the server (Ollama: ollama serve; vLLM: vllm serve MODEL; llama.cpp: "
            f"llama-server -m MODEL.gguf) or set base_url to where it listens, {cached}"
        )
    if why == "tls-plain":
        plain = urlunsplit(("http", *urlsplit(base_url)[1:]))
        return (
            "The server speaks plain http (a local vLLM, Ollama or llama.cpp does): set "
            f"base_url: {plain}, {cached}"
        )
    if why == "tls-cert":
        return (
            "This machine does not trust the server's certificate (self-signed, or "
            "issued by an in-house authority or a proxy that inspects https): set "
            "SSL_CERT_FILE to the CA bundle that signed it, or use the host name the "
            f"certificate is for, {cached}"
        )
    if why == "dropped":
        return (
            "The server took the request and closed the connection without a whole "
            "reply (it crashed or was killed, ran out of memory loading the model, or a "
            f"proxy in between cut it): see the server's log, raise max_retries, {cached}"
        )
    if why == "timeout":
        return (
            f"The server is slow to answer (a model still loading, a long reply): raise "
            f"timeout (now {timeout:g} s) or max_retries, {cached}"
        )
    if why == "rate":
        return f"The server is rate-limiting: raise max_retries or backoff, {cached}"
    if why == "api":
        return (
            "The body is not a chat completion: base_url leads to something other than "
            "an OpenAI-compatible API (a web page, a login proxy, a chat UI such as Open "
            "WebUI?). Set base_url to the server's API, e.g. http://127.0.0.1:11434/v1 "
            f"(Ollama) or http://127.0.0.1:8000/v1 (vLLM), {cached}"
        )
    if why == "length":
        return (
            "The model stopped at its token limit before it finished the lists (a "
            "reasoning model spends tokens thinking first): use an instruction-tuned "
            "model without reasoning, raise the server's context size (Ollama: num_ctx; "
            "llama.cpp: --ctx-size; vLLM: --max-model-len) or lower n_synonyms and "
            f"n_antonyms, {cached}"
        )
    if why == "decode":
        return (
            "The body does not match its Content-Encoding header (plain text labelled "
            "gzip?): check the compression settings of the server or of a proxy in "
            f"between, or set base_url to the server itself, {cached}"
        )
    if why == "size":
        return (
            "A chat reply with the lists asked for is a few kB: base_url may lead to "
            "something other than a chat API (a file, a stream), or the model did not "
            "stop. Check base_url, use an instruction-tuned model or lower n_synonyms "
            f"and n_antonyms, {cached}"
        )
    if why == "reply":
        fix = "" if json_mode else "set json_mode: true (vLLM, llama.cpp, Ollama) or "
        return (
            "The model did not answer with the asked lists: "
            f"{fix}use an instruction-tuned model, {cached}"
        )
    return f"The server failed: see its log, raise max_retries, {cached}"
