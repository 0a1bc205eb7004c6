"""What an ``llm`` config says about where requests go and what they carry: the
chat-completions URL made of ``base_url`` (:func:`chat_endpoint`, without credentials or
query string, for everything recorded or shown; :func:`request_url`, with the query
string, for the request itself), ``api_key_env``, checked to be the name of a
variable and not a key pasted in its place (:func:`check_key_env`), the headers that carry
the key it names (:func:`request_headers`), and the model and numbers a config must give
(:func:`check_config`)."""

from __future__ import annotations

import os
import re
from typing import Any
from urllib.parse import urlsplit, urlunsplit

from ..core.errors import ConfigError, HeuristicError
from ..core.redact import redact_url
from ._llm_http import check_key

__all__ = ["chat_endpoint", "check_config", "check_key_env", "request_headers", "request_url"]

#: What ``api_key_env`` must be: the name of an environment variable.
_ENV_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
#: A part (between underscores) of a name that looks like a key's random characters:
#: 16 or more letters and digits, both present (``gsk_ZQX9secretkey7731abcdef``).
_RANDOM_PART = re.compile(r"(?=[A-Za-z0-9]*[0-9])(?=[A-Za-z0-9]*[A-Za-z])[A-Za-z0-9]{16,}")


def check_config(
    model: Any, *, n_synonyms: Any, n_antonyms: Any, max_retries: Any, timeout: Any
) -> None:
    """ConfigError unless ``model`` is given, the counts are >= 0 and ``timeout`` > 0."""
    if not model:
        raise ConfigError(
            "Heuristic 'llm' needs 'model', e.g. heuristic: {name: llm, model: gpt-4o, "
            "base_url: http://127.0.0.1:8000/v1}."
        )
    for field, value in (
        ("n_synonyms", n_synonyms),
        ("n_antonyms", n_antonyms),
        ("max_retries", max_retries),
    ):
        if int(value) < 0:
            raise ConfigError(f"Heuristic 'llm': {field!r} must be >= 0; got {value!r}.")
    if float(timeout) <= 0:
        raise ConfigError(f"Heuristic 'llm': 'timeout' must be positive; got {timeout!r}.")


def request_headers(api_key_env: str | None) -> dict[str, str]:
    """The headers of every request: JSON, and the key in the variable ``api_key_env``
    names as a Bearer token (HeuristicError, never showing it, when it is unset, empty or
    cannot be sent)."""
    headers = {"Content-Type": "application/json", "Accept": "application/json"}
    if api_key_env:
        key = os.environ.get(api_key_env)
        if key is None or not key.strip():
            state = "is not set" if key is None else "is empty"
            raise HeuristicError(
                f"Heuristic 'llm': environment variable {api_key_env!r} (api_key_env) "
                f"{state}. Export the API key there, or set api_key_env: null for a "
                "server without authentication."
            )
        headers["Authorization"] = f"Bearer {check_key(key, api_key_env)}"
    return headers


def check_key_env(value: Any) -> str | None:
    """``api_key_env`` as given, when it names an environment variable; ConfigError (which
    never shows the value: it may be a key pasted in the wrong place) otherwise.

    A value that is a name but looks like a key (a part between underscores of 16
    characters or more, letters and digits mixed, as in ``gsk_ZQX9secretkey7731abcdef``
    or ``hf_...``) is refused too, unless a variable of that name is set."""
    if value is None or value == "":
        return value
    fix = (
        "Export the key in a variable (export OPENAI_API_KEY=...) and set api_key_env to "
        "its name (api_key_env: OPENAI_API_KEY)."
    )
    if not isinstance(value, str) or not _ENV_NAME.fullmatch(value):
        raise ConfigError(
            "Heuristic 'llm': api_key_env must be the NAME of the environment variable "
            "that holds the API key (letters, digits and underscores, not starting with "
            "a digit); the value given is not such a name (it is not shown: it may be the "
            f"key itself). {fix}"
        )
    random_part = any(_RANDOM_PART.fullmatch(part) for part in value.split("_"))
    if random_part and value not in os.environ:
        raise ConfigError(
            "Heuristic 'llm': api_key_env must be the NAME of the environment variable "
            "that holds the API key, not the key: the value given looks like a key (not "
            f"shown) and no variable of that name is set. {fix}"
        )
    return value


def chat_endpoint(base_url: str) -> str:
    """The chat-completions URL for ``base_url``, without credentials or query string.

    Credentials written into the URL (``https://user:key@host``) are dropped: they are
    never sent, logged or cached. Put the key in the variable named by ``api_key_env``.
    """
    try:
        parts = urlsplit(str(base_url).strip())
        ok = parts.scheme in ("http", "https") and bool(parts.hostname)
        port = parts.port if ok else None
    except ValueError:  # a malformed port or address
        ok = False
    if not ok:
        shown = redact_url(str(base_url))  # no query value, no user-info
        text = str(base_url).strip()
        guess = ""
        if text and "://" not in text:  # "127.0.0.1:8000/v1", "localhost:11434/v1"
            try:
                if urlsplit(f"http://{text}").hostname:
                    guess = f" Did you mean base_url: {redact_url('http://' + text)}?"
            except ValueError:
                pass
        raise ConfigError(
            f"Heuristic 'llm': base_url {shown!r} is not an http(s) URL.{guess} E.g. "
            "http://127.0.0.1:8000/v1 (vLLM), http://127.0.0.1:11434/v1 (Ollama), "
            "http://127.0.0.1:8080/v1 (llama.cpp)."
        )
    netloc = parts.hostname if ":" not in parts.hostname else f"[{parts.hostname}]"
    if port:
        netloc += f":{port}"
    path = parts.path.rstrip("/")
    if not path.endswith("/chat/completions"):
        path += "/chat/completions"
    return urlunsplit((parts.scheme, netloc, path, "", ""))


def request_url(base_url: str) -> str:
    """The URL requests go to: :func:`chat_endpoint` with ``base_url``'s query string
    (``?api-version=...``, which Azure-style endpoints require), which
    :func:`chat_endpoint` leaves out of everything recorded or shown.

    >>> request_url("https://h/openai/deployments/gpt4o?api-version=2024-02-01")
    'https://h/openai/deployments/gpt4o/chat/completions?api-version=2024-02-01'
    """
    query = urlsplit(str(base_url).strip()).query
    return chat_endpoint(base_url) + (f"?{query}" if query else "")
