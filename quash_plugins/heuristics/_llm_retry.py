"""One question of the ``llm`` heuristic to its server, attempt by attempt.

:func:`ask_with_retries` sends the request until a reply is usable, retrying what may pass
(429, 5xx, time-outs, dropped connections, unusable replies) after a growing wait or the
server's Retry-After. A request that got no reply is told by :func:`request_failure`; a
reply by :func:`judge_response`: the cleaned query set of a usable one, else why it failed
when a retry may help, else nothing (a redirect or a status that is not retried, whose
error :func:`status_error` words, with :func:`status_hint`). The error after the last
attempt is :func:`no_reply_error`. Whatever the server said passes through :func:`redact`
with the secrets given (the key and base_url's credential-like query values) before it is
shown or logged.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterable
from typing import TYPE_CHECKING, Any, NamedTuple

from ..core.errors import HeuristicError
from ..core.redact import redact
from ._llm_http import (
    MAX_REPLY_BYTES,
    MAX_RETRY_AFTER,
    REDIRECT_STATUSES,
    ReplyError,
    connect_reason,
    content_of,
    failure_fix,
    not_found_hint,
    proxy_note,
    redirect_hint,
    retry_after,
    snippet,
    tls_failure,
)
from ._parse import clean_lists, parse_reply

if TYPE_CHECKING:
    from ._llm import LLMHeuristic

__all__ = [
    "RETRY_STATUSES",
    "Outcome",
    "ask_with_retries",
    "judge_response",
    "no_reply_error",
    "request_failure",
    "status_error",
    "status_hint",
]

#: HTTP statuses worth retrying.
RETRY_STATUSES = frozenset({408, 409, 425, 429, 500, 502, 503, 504})

#: The failures a proxy in between may have caused: the last error names the proxy.
_PROXIED = ("connect", "tls-plain", "tls-cert", "dropped", "timeout", "status", "api", "decode")


class Outcome(NamedTuple):
    """A reply judged: ``lists`` (synonyms, antonyms) when usable; else ``last`` (what
    went wrong, redacted) and ``why`` (its kind, for :func:`failure_fix`) when a retry may
    help, with ``wait`` the server's Retry-After; else all empty (not retried)."""

    lists: tuple[list[str], list[str]] | None = None
    last: str = ""
    why: str = ""
    wait: float | None = None


def ask_with_retries(
    h: LLMHeuristic,
    query: str,
    secrets: list[str],
    *,
    httpx: Any,
    send: Callable[[], Any],
    hint: Callable[[int, str], str],
    log: logging.Logger,
) -> tuple[list[str], list[str]]:
    """Cleaned ``(synonyms, antonyms)`` for ``query`` from the first usable reply to
    ``send()`` (one request of ``h``), within ``h.max_retries`` retries; HeuristicError
    otherwise. ``hint``: :func:`status_error`'s; ``log``: the heuristic's logger, which
    says each attempt and each failure."""
    last, why = "no attempt made", "connect"
    attempts = h.max_retries + 1
    for attempt in range(attempts):
        wait = h.backoff * (2**attempt)
        log.info(
            "llm: asking %s (%s) for %r, attempt %d/%d",
            h.endpoint,
            h.model,
            query,
            attempt + 1,
            attempts,
        )
        try:
            resp = send()
        except httpx.RequestError as exc:
            last, why = request_failure(httpx, exc, h.endpoint, h.timeout, secrets)
        else:
            outcome = judge_response(resp, query, h.n_synonyms, h.n_antonyms, secrets)
            if outcome.lists is not None:
                return outcome.lists
            if not outcome.why:  # a redirect, or a status not worth retrying
                raise status_error(resp, h.endpoint, secrets, hint)
            last, why = outcome.last, outcome.why
            if outcome.wait is not None:  # the server's Retry-After
                wait = max(wait, outcome.wait)
        if why in ("tls-plain", "tls-cert"):  # the same on every attempt: no retry
            log.warning("llm: %s %s", h.endpoint, last)
            attempts = attempt + 1
            break
        if attempt + 1 < attempts:
            wait = min(wait, MAX_RETRY_AFTER)
            log.warning("llm: %s %s; retrying in %.3g s", h.endpoint, last, wait)
            time.sleep(wait)
        else:
            log.warning("llm: %s %s", h.endpoint, last)
    raise no_reply_error(
        endpoint=h.endpoint,
        model=h.model,
        query=query,
        attempts=attempts,
        last=last,
        why=why,
        timeout=h.timeout,
        json_mode=h.json_mode,
        base_url=h.base_url,
    )


def _dropped_errors(httpx: Any) -> tuple[type[Exception], ...]:
    """httpx's errors for a connection the server closed after it was made (not a
    connection that could not be made: httpx.ConnectError)."""
    return (httpx.ReadError, httpx.WriteError, httpx.CloseError, httpx.RemoteProtocolError)


def request_failure(
    httpx: Any, exc: Exception, endpoint: str, timeout: float, secrets: Iterable[str]
) -> tuple[str, str]:
    """``(last, why)`` for a request that raised ``exc`` (an ``httpx.RequestError``)."""
    secrets = list(secrets)
    if isinstance(exc, httpx.TimeoutException):
        return f"timed out after {timeout:g} s", "timeout"
    if isinstance(exc, _dropped_errors(httpx)):
        # the server took the request and closed the connection without a whole reply:
        # it is there (crashed, killed, or a proxy cut it off)
        text = redact(str(exc), secrets)
        last = (
            "the server closed the connection before a whole reply "
            f"({type(exc).__name__}{': ' + text if text else ''})"
        )
        return last, "dropped"
    if isinstance(exc, httpx.TransportError):
        last = connect_reason(exc, endpoint, secrets)
        return last, {"plain": "tls-plain", "cert": "tls-cert"}.get(
            tls_failure(exc) or "", "connect"
        )
    # none other is known; never "unexpected"
    return f"request failed ({type(exc).__name__}: {redact(exc, secrets)})", "status"


def judge_response(
    resp: Any, query: str, n_synonyms: int, n_antonyms: int, secrets: Iterable[str]
) -> Outcome:
    """The :class:`Outcome` of the reply ``resp`` to a request about ``query``."""
    secrets = list(secrets)
    status = resp.status_code
    if resp.decode_error:
        encoding = resp.headers.get("content-encoding", "")
        last = (
            f"status {status} with a body that cannot be decoded as its "
            f"Content-Encoding {encoding!r} says ({redact(resp.decode_error, secrets)})"
        )
        return Outcome(last=last, why="decode")
    if status == 200 and resp.truncated:
        last = (
            f"status 200 with a reply over {MAX_REPLY_BYTES // 2**20} MiB "
            "(the most the llm heuristic reads), left unread"
        )
        return Outcome(last=last, why="size")
    if status == 200:
        finish = None
        try:
            content, finish = content_of(resp, secrets)
            syn, ant = parse_reply(content, secrets, finish == "length")
            # A reply that echoes a credential never reaches a query set, a cache file
            # or a log line.
            lists = clean_lists(
                query, syn, ant, n_synonyms, n_antonyms, keep=lambda w: redact(w, secrets) == w
            )
            return Outcome(lists=lists)
        except ValueError as exc:
            last = f"status 200 with an unusable reply ({redact(exc, secrets)})"
            why = exc.kind if isinstance(exc, ReplyError) else "reply"
            if finish == "length":  # a reply cut off at the token limit
                last += " (finish_reason 'length': the model ran out of tokens)"
                why = "length"
            return Outcome(last=last, why=why)
    if status in RETRY_STATUSES:
        last, why = f"status {status}", "rate" if status == 429 else "status"
        if resp.text.strip():
            last += f": {snippet(resp.text, secrets, 120)}"
        return Outcome(last=last, why=why, wait=retry_after(resp))
    return Outcome()


def status_error(
    resp: Any, endpoint: str, secrets: Iterable[str], hint: Callable[[int, str], str]
) -> HeuristicError:
    """The error for a reply whose status is not retried: a redirect (never followed), or
    another status, with ``hint(status, body)`` (:func:`status_hint`) said after it."""
    secrets = list(secrets)
    status = resp.status_code
    if status in REDIRECT_STATUSES:
        location = resp.headers.get("location")
        return HeuristicError(
            f"Heuristic 'llm': {endpoint} answered status {status}, a "
            f"redirect.{redirect_hint(endpoint, location, secrets)}"
        )
    return HeuristicError(
        f"Heuristic 'llm': {endpoint} answered status {status}: "
        f"{snippet(resp.text, secrets)}."
        f"{redact(hint(status, resp.text), secrets)}"
        f"{proxy_note(endpoint)}"
    )


def status_hint(
    status: int,
    body: str,
    *,
    endpoint: str,
    model: str,
    api_key_env: str | None,
    json_mode: bool,
    known_models: Callable[[], tuple[str, list[str]]],
) -> str:
    """What to do about a status that is not retried (401, 403, 404, 400...); ``body``:
    the server's reply, which a 400 about the model is told by; ``known_models``: the
    server's models, asked only when needed (:func:`~._llm_http.known_models`)."""
    if status in (401, 403):
        if api_key_env:
            return f" Check the API key in {api_key_env!r} (api_key_env)."
        return (
            " The server wants a key: set api_key_env to the name of the environment "
            "variable that holds it (no key was sent)."
        )
    if status == 404:
        base, models = known_models()
        return not_found_hint(endpoint, model, base, models)
    if status in (400, 422) and "model" in body.lower():
        # LiteLLM, some gateways and older vLLM answer an unknown model with a 400
        base, models = known_models()
        if models and model not in models:
            return not_found_hint(endpoint, model, base, models)
    if status in (400, 422) and json_mode:
        return (
            " json_mode: true sends response_format, which this server may not support: "
            "set json_mode: false (replies are parsed anyway)."
        )
    return ""


def no_reply_error(
    *,
    endpoint: str,
    model: str,
    query: str,
    attempts: int,
    last: str,
    why: str,
    timeout: float,
    json_mode: bool,
    base_url: str,
) -> HeuristicError:
    """The error when no attempt got a usable reply: the last failure and what to do."""
    return HeuristicError(
        f"Heuristic 'llm': no usable reply from {endpoint} (model {model!r}) for "
        f"{query!r} after {attempts} attempt(s); last: {last}. "
        f"{failure_fix(why, timeout, json_mode, base_url)}"
        f"{proxy_note(endpoint) if why in _PROXIED else ''}"
    )
