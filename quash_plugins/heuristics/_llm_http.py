"""The ``llm`` heuristic's side of HTTP: the client, reading a chat-completions reply,
and saying in words what went wrong.

Everything that quotes a server's words passes them through :func:`redact` with the API
key first. A loopback endpoint (``127.0.0.1``, ``::1``, ``localhost``) is reached
directly, never through a proxy named by ``HTTP_PROXY``/``HTTPS_PROXY``/``ALL_PROXY``: a
proxy cannot reach this machine's loopback, so on a cluster that sets one a local Ollama
or vLLM would otherwise look down. Other hosts follow the environment (``NO_PROXY``
included), and a failure names the proxy it went through.
"""

from __future__ import annotations

import ipaddress
import urllib.request
from typing import Any
from urllib.parse import urlsplit, urlunsplit

from ..core.errors import HeuristicError
from ..core.redact import redact

#: How many of the server's model names a 404 message lists.
MAX_MODELS_SHOWN = 12


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


def connect_reason(exc: Any, endpoint: str, key: str = "") -> str:
    """Why a connection failed, in words: refused, an unknown host, or httpx's reason;
    through which proxy, when the environment names one for ``endpoint``."""
    text = redact(str(exc), [key])
    parts = urlsplit(endpoint)
    low = text.lower()
    proxy = env_proxy(endpoint)
    if proxy is not None:
        return (
            f"connection failed through the proxy {proxy} from the environment "
            f"({type(exc).__name__}{': ' + text if text else ''})"
        )
    if "refused" in low:
        return f"connection refused (nothing listens on {parts.netloc})"
    unknown = ("name or service not known", "nodename nor servname", "name resolution")
    if any(w in low for w in unknown) or "getaddrinfo" in low:
        return f"connection failed (host {parts.hostname!r} not found)"
    return f"connection failed ({type(exc).__name__}{': ' + text if text else ''})"


def content_of(resp: Any, key: str = "") -> tuple[str, str | None]:
    """The assistant message of a chat-completions response and its ``finish_reason``;
    :class:`ReplyError` when the body is not a chat completion or holds no text."""
    try:
        data = resp.json()
    except ValueError:
        raise ReplyError(f"body is not JSON: {snippet(resp.text, [key])}", "api") from None
    try:
        choice = data["choices"][0]
        content = choice["message"]["content"]
    except (KeyError, IndexError, TypeError):
        raise ReplyError(
            f"no choices[0].message.content in {snippet(resp.text, [key])}", "api"
        ) from None
    finish = choice.get("finish_reason") if isinstance(choice, dict) else None
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


def retry_after(resp: Any) -> float:
    value = resp.headers.get("retry-after")
    try:
        return max(0.0, float(value)) if value is not None else 0.0
    except ValueError:
        return 0.0


def snippet(text: str, secrets: list[str] | tuple[str, ...] = (), n: int = 160) -> str:
    """The start of a server reply, credentials redacted before it is shortened."""
    text = " ".join(redact(text, secrets).split())
    return repr(text if len(text) <= n else text[:n] + "...")


def known_models(
    client: Any, endpoint: str, headers: dict[str, str], timeout: float = 5.0
) -> tuple[str, list[str]]:
    """Ask the server which models it serves: ``GET .../models`` beside ``endpoint``, then
    at ``/v1/models`` of its origin. Returns (the base URL that answered, the model ids);
    ``("", [])`` when neither does. Used only to explain a 404."""
    parts = urlsplit(endpoint)
    base = parts.path.removesuffix("/chat/completions")
    origin = (parts.scheme, parts.netloc)
    tried = []
    for path in (base, "/v1"):
        url = urlunsplit((*origin, path.rstrip("/") + "/models", "", ""))
        if url in tried:
            continue
        tried.append(url)
        try:
            resp = client.get(url, headers=headers, timeout=timeout)
            data = resp.json() if resp.status_code == 200 else None
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
