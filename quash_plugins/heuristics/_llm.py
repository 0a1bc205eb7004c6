"""``llm`` heuristic: synonyms and antonyms from any OpenAI-compatible chat endpoint.

Works with hosted APIs and with local vLLM, Ollama (``/v1``) and llama.cpp servers: all
of them speak ``POST {base_url}/chat/completions``. Query sets are cached on disk, so an
experiment can be re-run with ``offline: true`` and no server at all.
"""

from __future__ import annotations

import json
import logging
import os
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from ..core.errors import ConfigError, HeuristicError, QuashError
from ..core.interfaces import ExpansionContext, Heuristic
from ..core.redact import RedactingFilter, redact, redact_url, url_secrets
from ..core.types import QuerySet
from ._llm_cache import cache_file_name, llm_cache_root
from ._llm_endpoint import chat_endpoint, check_key_env, request_url
from ._llm_http import (
    MAX_REPLY_BYTES,
    MAX_RETRY_AFTER,
    REDIRECT_STATUSES,
    ReplyError,
    bounded_request,
    check_key,
    cleartext_host,
    client_options,
    connect_reason,
    content_of,
    failure_fix,
    known_models,
    not_found_hint,
    proxy_note,
    redirect_hint,
    retry_after,
    snippet,
    tls_failure,
)
from ._parse import clean_lists, parse_reply

log = logging.getLogger(__name__)
# Whoever configures logging, nothing this module logs carries a key-like token.
log.addFilter(RedactingFilter())
# httpx logs each request's URL at INFO, query string included (base_url's ?key=...): the
# values of credential-like parameters are masked there too.
_httpx_log = logging.getLogger("httpx")
if not any(isinstance(f, RedactingFilter) for f in _httpx_log.filters):
    _httpx_log.addFilter(RedactingFilter())

#: Bumped whenever the prompt wording changes; part of every cache key.
PROMPT_VERSION = "quash-llm-2"
#: The endpoint asked when a config gives no ``base_url`` (vLLM's default port).
LLM_DEFAULT_BASE_URL = "http://127.0.0.1:8000/v1"

SYSTEM_PROMPT = (
    "You help a robot find things in a map of an indoor or outdoor scene. "
    "You reply with a single JSON object and no other text."
)

USER_PROMPT = """The robot was asked to find: "{query}".

1. List {n_synonyms} semantic synonyms: words or short noun phrases that refer to the same \
thing or to things a person would accept as a match, such as closely related words, more \
specific kinds (sub-classes), more general kinds (super-classes) and objects that are part \
of it or usually attached to it.
2. List {n_antonyms} semantic antonyms: objects, furniture, structures, surfaces or places \
that plausibly appear in the same environment as "{query}" but are clearly not it.

Use lowercase singular nouns or short noun phrases, with no explanations and no duplicates. \
Reply exactly in this form:
{{"synonyms": ["...", "..."], "antonyms": ["...", "..."]}}"""

#: HTTP statuses worth retrying.
RETRY_STATUSES = frozenset({408, 409, 425, 429, 500, 502, 503, 504})

#: Hosts warned about once: an http:// endpoint elsewhere that is sent the key.
_CLEARTEXT_WARNED: set[str] = set()


def _dropped_errors(httpx: Any) -> tuple[type[Exception], ...]:
    """httpx's errors for a connection the server closed after it was made (not a
    connection that could not be made: httpx.ConnectError)."""
    return (httpx.ReadError, httpx.WriteError, httpx.CloseError, httpx.RemoteProtocolError)


def _import_httpx() -> Any:
    try:
        import httpx
    except ImportError:
        raise HeuristicError(
            "Heuristic 'llm' needs httpx: pip install \"quash-plugins[llm]\""
        ) from None
    return httpx


class LLMHeuristic(Heuristic):
    """Ask a chat model for synonyms and antonyms of the query.

    Parameters
    ----------
    model
        Model name as the server knows it (``"gpt-4o"``, ``"llama3.1:8b"``...).
    base_url
        OpenAI-compatible base URL ending in ``/v1`` (or the full chat-completions URL).
    api_key_env
        Name of the environment variable holding the API key, sent as a Bearer token.
        None for local servers without authentication. The key itself is never logged,
        cached or recorded; a value that is not a variable name (or looks like a key) is
        refused without being shown.
    n_synonyms, n_antonyms
        How many of each to ask for (the paper: 20 and 20).
    temperature
        Sampling temperature sent to the server.
    timeout
        Seconds per HTTP request, for the whole of it: connecting, sending, waiting, and
        reading the reply (at most :data:`~._llm_http.MAX_REPLY_BYTES`, 4 MiB).
    max_retries
        Retries after the first attempt on 429, 5xx, time-outs, connection errors,
        unparseable replies, bodies that cannot be decoded and replies over the size limit.
    backoff
        Base delay in seconds; attempt ``k`` waits ``backoff * 2**k`` (or the server's
        ``Retry-After``, at most 60 s).
    offline
        Serve from the cache only; a miss is an error. Needs no server and no key.
    cache_dir
        Where query sets are cached; default ``$QUASH_CACHE_DIR/llm`` or the user cache.
    cache
        False disables the cache (neither read nor written).
    json_mode
        Send ``response_format: {"type": "json_object"}`` (not every server supports it).
    send_seed
        Send the config's seed in the request (honoured by most servers).

    Examples
    --------
    >>> h = LLMHeuristic(model="llama3.1:8b", base_url="http://127.0.0.1:11434/v1")
    >>> h.endpoint
    'http://127.0.0.1:11434/v1/chat/completions'
    """

    name = "llm"

    @staticmethod
    def conformance_params(tmp_path: Path) -> dict[str, Any]:
        """Offline parameters with a pre-filled cache, so the kit needs no server."""
        params = {
            "model": "conformance-model",
            "base_url": "http://127.0.0.1:9/v1",
            "offline": True,
            "cache_dir": str(Path(tmp_path) / "llm-cache"),
        }
        h = LLMHeuristic(**params)
        h._write_cache("chair", ["seat", "armchair"], ["table", "lamp"])
        return params

    def __init__(
        self,
        model: str | None = None,
        base_url: str = LLM_DEFAULT_BASE_URL,
        api_key_env: str | None = None,
        n_synonyms: int = 20,
        n_antonyms: int = 20,
        temperature: float = 0.0,
        timeout: float = 60.0,
        max_retries: int = 4,
        backoff: float = 1.0,
        offline: bool = False,
        cache_dir: str | None = None,
        cache: bool = True,
        json_mode: bool = False,
        send_seed: bool = True,
    ) -> None:
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
        self.api_key_env = check_key_env(api_key_env)
        self.model = str(model)
        self.endpoint = chat_endpoint(base_url)
        # the query string goes with each request, never into a cache key, provenance or
        # a message (it may hold a credential: ?key=, ?sig=, ?code=)
        self._url = request_url(base_url)
        self._url_secrets = url_secrets(self._url)
        if urlsplit(str(base_url).strip()).netloc.count("@"):
            log.warning(
                "llm: base_url %s carries credentials; they are never sent. Put the key in "
                "the environment variable named by api_key_env.",
                redact_url(base_url),
            )
        self.base_url = redact_url(base_url)
        self.n_synonyms = int(n_synonyms)
        self.n_antonyms = int(n_antonyms)
        self.temperature = float(temperature)
        self.timeout = float(timeout)
        self.max_retries = int(max_retries)
        self.backoff = float(backoff)
        self.offline = bool(offline)
        self.cache_dir = cache_dir
        self.cache = bool(cache)
        self.json_mode = bool(json_mode)
        self.send_seed = bool(send_seed)
        #: Query sets this object got from the server and cached (named when a later
        #: query fails, so that a long run knows a re-run resumes).
        self._cached_now = 0

    # ------------------------------------------------------------------ provenance
    def params(self) -> dict[str, Any]:
        return {
            "model": self.model,
            "endpoint": self.endpoint,
            "api_key_env": self.api_key_env,
            "n_synonyms": self.n_synonyms,
            "n_antonyms": self.n_antonyms,
            "temperature": self.temperature,
            "offline": self.offline,
            "json_mode": self.json_mode,
            "prompt_version": PROMPT_VERSION,
        }

    # ------------------------------------------------------------------ cache
    def _cache_root(self) -> Path:
        return llm_cache_root(self.cache_dir)

    def cache_key(self, query: str, seed: int | None = None) -> dict[str, Any]:
        """What identifies a cached query set (no secrets).

        A sampled reply (``temperature > 0``) also depends on the temperature and on the
        seed sent with the request, so both join the key then: another temperature or
        seed asks the server again. At temperature 0 (greedy decoding, the default) the
        seed changes nothing, and the key is the one it always was, so existing caches
        keep serving. ``json_mode`` is not in the key: it changes how the reply is
        wrapped, not what is asked, and replies are parsed alike either way."""
        key: dict[str, Any] = {
            "endpoint": self.endpoint,
            "model": self.model,
            "prompt_version": PROMPT_VERSION,
            "query": query,
            "n_synonyms": self.n_synonyms,
            "n_antonyms": self.n_antonyms,
        }
        if self.temperature > 0:
            key["temperature"] = self.temperature
            key["seed"] = int(seed) if self.send_seed and seed is not None else None
        return key

    def cache_path(self, query: str, seed: int | None = None) -> Path:
        return self._cache_root() / cache_file_name(self.cache_key(query, seed))

    def _read_cache(self, query: str, seed: int | None = None) -> dict[str, Any] | None:
        path = self.cache_path(query, seed)
        if not path.exists() and not path.is_symlink():
            return None
        if path.is_symlink() or not path.is_file():
            log.warning("ignoring LLM cache entry %s: not a regular file", path)
            return None
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            log.warning("ignoring unreadable LLM cache file %s: %s", path, exc)
            return None
        if not isinstance(data, dict) or data.get("key") != self.cache_key(query, seed):
            return None
        lists = [data.get(side) for side in ("synonyms", "antonyms")]
        if not all(isinstance(v, list) and all(isinstance(w, str) for w in v) for v in lists):
            log.warning(
                "ignoring LLM cache file %s: 'synonyms' and 'antonyms' must be lists of strings",
                path,
            )
            return None
        # a file edited by hand is cleaned as a reply is (case, duplicates, the query, caps)
        syn, ant = clean_lists(query, *lists, self.n_synonyms, self.n_antonyms)
        return {**data, "synonyms": syn, "antonyms": ant}

    def _write_cache(
        self, query: str, synonyms: list[str], antonyms: list[str], seed: int | None = None
    ) -> Path | None:
        """Cache a query set; its file, or None (with a warning) when it cannot be written."""
        from ..core.atomic import atomic_write_text
        from ..core.cache_dirs import make_private_dirs

        path = self.cache_path(query, seed)
        record = {
            "key": self.cache_key(query, seed),
            "synonyms": synonyms,
            "antonyms": antonyms,
            "temperature": self.temperature,
            "created": datetime.now(UTC).isoformat(timespec="seconds"),
        }
        try:
            make_private_dirs(path.parent)
            atomic_write_text(path, json.dumps(record, indent=1, ensure_ascii=False))
        # unwritable, or a link or folder planted at the cache path (never followed)
        except (OSError, QuashError) as exc:
            log.warning("llm: query set for %r not cached: %s", query, exc)
            return None
        return path

    # ------------------------------------------------------------------ expansion
    def expand(self, query: str, context: ExpansionContext | None = None) -> QuerySet:
        seed = context.seed if context is not None else None
        cached = self._read_cache(query, seed) if self.cache else None
        source = "cache"
        if cached is not None:
            synonyms, antonyms = list(cached["synonyms"]), list(cached["antonyms"])
            log.info("llm: %r served from cache %s", query, self.cache_path(query, seed))
            if not synonyms and not antonyms:  # a file edited by hand
                log.warning(
                    "llm: the cached set for %r (%s) holds no synonyms and no antonyms",
                    query,
                    self.cache_path(query, seed),
                )
        elif self.offline:
            where = self._cache_root() if self.cache else "(cache disabled)"
            sampled = (
                f", temperature {self.temperature}, seed {self.cache_key(query, seed)['seed']}"
                if self.temperature > 0
                else ""
            )
            raise HeuristicError(
                f"Heuristic 'llm' is offline and has no cached query set for {query!r} "
                f"(model {self.model!r}, endpoint {self.endpoint}, prompt {PROMPT_VERSION}, "
                f"n_synonyms {self.n_synonyms}, n_antonyms {self.n_antonyms}{sampled}) in "
                f"{where}. Run once with offline: false, or point cache_dir at the cache "
                "that has it."
            )
        else:
            try:
                synonyms, antonyms = self.ask(query, seed)
            except HeuristicError as exc:
                if self.cache and self._cached_now:
                    # a long run that stops at one query loses none of the answers before it
                    raise HeuristicError(
                        f"{exc} The {self._cached_now} query set(s) this run got from the "
                        f"server before {query!r} are cached in {self._cache_root()}: a "
                        "re-run asks only for the others."
                    ) from None
                raise
            source = "server"
            if len(synonyms) < self.n_synonyms or len(antonyms) < self.n_antonyms:
                log.info(
                    "llm: %r: the model gave %d of %d synonyms and %d of %d antonyms (after "
                    "dropping repeats, the query, over-long items and antonyms that are also synonyms)",
                    query,
                    len(synonyms),
                    self.n_synonyms,
                    len(antonyms),
                    self.n_antonyms,
                )
            if not synonyms and not antonyms:
                log.warning(
                    "llm: %s (%s) returned no synonyms and no antonyms for %r: the query "
                    "alone is the positive%s",
                    self.endpoint,
                    self.model,
                    query,
                    "; not cached, so the next run asks again" if self.cache else "",
                )
            elif self.cache and self._write_cache(query, synonyms, antonyms, seed):
                self._cached_now += 1
        extra: dict[str, Any] = {"source": source, "prompt_version": PROMPT_VERSION}
        if self.cache and self.cache_path(query, seed).is_file():  # none when not written
            extra["cache_file"] = str(self.cache_path(query, seed))
        return QuerySet(query, [query, *synonyms], antonyms, self.provenance(context, **extra))

    def request_body(self, query: str, seed: int | None = None) -> dict[str, Any]:
        """The chat-completions request for ``query``."""
        user = USER_PROMPT.format(
            query=query, n_synonyms=self.n_synonyms, n_antonyms=self.n_antonyms
        )
        body: dict[str, Any] = {
            "model": self.model,
            "messages": [
                {"role": "system", "content": SYSTEM_PROMPT},
                {"role": "user", "content": user},
            ],
            "temperature": self.temperature,
        }
        if self.json_mode:
            body["response_format"] = {"type": "json_object"}
        if self.send_seed and seed is not None:
            body["seed"] = int(seed)
        return body

    def _headers(self) -> dict[str, str]:
        headers = {"Content-Type": "application/json", "Accept": "application/json"}
        if self.api_key_env:
            key = os.environ.get(self.api_key_env)
            if key is None or not key.strip():
                state = "is not set" if key is None else "is empty"
                raise HeuristicError(
                    f"Heuristic 'llm': environment variable {self.api_key_env!r} (api_key_env) "
                    f"{state}. Export the API key there, or set api_key_env: null for a "
                    "server without authentication."
                )
            headers["Authorization"] = f"Bearer {check_key(key, self.api_key_env)}"
        return headers

    def ask(self, query: str, seed: int | None = None) -> tuple[list[str], list[str]]:
        """Call the server (with retries) and return cleaned ``(synonyms, antonyms)``.

        Whatever the server answers is passed through :func:`redact` (with the key itself
        and base_url's credential-like query values) before it reaches an error message or
        a log line. Each attempt lasts at most ``timeout`` seconds in all and reads at most
        :data:`~._llm_http.MAX_REPLY_BYTES` of reply; redirects are never followed.
        """
        httpx = _import_httpx()
        body = self.request_body(query, seed)
        headers = self._headers()
        key = headers.get("Authorization", "").removeprefix("Bearer ")
        secrets = [key, *self._url_secrets]
        if key:
            self._warn_cleartext()
        last, why = "no attempt made", "connect"
        attempts = self.max_retries + 1
        # one connection per request: bounded_request's deadline watches the sockets it
        # sees connected
        with httpx.Client(
            timeout=httpx.Timeout(self.timeout),
            limits=httpx.Limits(max_keepalive_connections=0),
            **client_options(self.endpoint),
        ) as client:
            for attempt in range(attempts):
                wait = self.backoff * (2**attempt)
                log.info(
                    "llm: asking %s (%s) for %r, attempt %d/%d",
                    self.endpoint,
                    self.model,
                    query,
                    attempt + 1,
                    attempts,
                )
                try:
                    resp = bounded_request(
                        client, "POST", self._url, json=body, headers=headers, timeout=self.timeout
                    )
                except httpx.TimeoutException:
                    last, why = f"timed out after {self.timeout:g} s", "timeout"
                except _dropped_errors(httpx) as exc:
                    # the server took the request and closed the connection without a
                    # whole reply: it is there (crashed, killed, or a proxy cut it off)
                    text = redact(str(exc), secrets)
                    last = (
                        "the server closed the connection before a whole reply "
                        f"({type(exc).__name__}{': ' + text if text else ''})"
                    )
                    why = "dropped"
                except httpx.TransportError as exc:
                    last = connect_reason(exc, self.endpoint, secrets)
                    why = {"plain": "tls-plain", "cert": "tls-cert"}.get(
                        tls_failure(exc) or "", "connect"
                    )
                except httpx.RequestError as exc:  # none other is known; never "unexpected"
                    last = f"request failed ({type(exc).__name__}: {redact(exc, secrets)})"
                    why = "status"
                else:
                    status = resp.status_code
                    if resp.decode_error:
                        encoding = resp.headers.get("content-encoding", "")
                        last = (
                            f"status {status} with a body that cannot be decoded as its "
                            f"Content-Encoding {encoding!r} says ({redact(resp.decode_error, secrets)})"
                        )
                        why = "decode"
                    elif status == 200 and resp.truncated:
                        last = (
                            f"status 200 with a reply over {MAX_REPLY_BYTES // 2**20} MiB "
                            "(the most the llm heuristic reads), left unread"
                        )
                        why = "size"
                    elif status == 200:
                        finish = None
                        try:
                            content, finish = content_of(resp, secrets)
                            syn, ant = parse_reply(content, secrets, finish == "length")
                            # A reply that echoes a credential never reaches a query set,
                            # a cache file or a log line.
                            return clean_lists(
                                query,
                                syn,
                                ant,
                                self.n_synonyms,
                                self.n_antonyms,
                                keep=lambda w: redact(w, secrets) == w,
                            )
                        except ValueError as exc:
                            reason = redact(exc, secrets)
                            last = f"status 200 with an unusable reply ({reason})"
                            why = exc.kind if isinstance(exc, ReplyError) else "reply"
                            if finish == "length":  # a reply cut off at the token limit
                                last += " (finish_reason 'length': the model ran out of tokens)"
                                why = "length"
                    elif status in RETRY_STATUSES:
                        last, why = f"status {status}", "rate" if status == 429 else "status"
                        if resp.text.strip():
                            last += f": {snippet(resp.text, secrets, 120)}"
                        wait = max(wait, retry_after(resp))
                    elif status in REDIRECT_STATUSES:
                        location = resp.headers.get("location")
                        raise HeuristicError(
                            f"Heuristic 'llm': {self.endpoint} answered status {status}, a "
                            f"redirect.{redirect_hint(self.endpoint, location, secrets)}"
                        )
                    else:
                        raise HeuristicError(
                            f"Heuristic 'llm': {self.endpoint} answered status {status}: "
                            f"{snippet(resp.text, secrets)}."
                            f"{redact(self._status_hint(status, client, resp.text), secrets)}"
                            f"{proxy_note(self.endpoint)}"
                        )
                if why in ("tls-plain", "tls-cert"):  # the same on every attempt: no retry
                    log.warning("llm: %s %s", self.endpoint, last)
                    attempts = attempt + 1
                    break
                if attempt + 1 < attempts:
                    wait = min(wait, MAX_RETRY_AFTER)
                    log.warning("llm: %s %s; retrying in %.3g s", self.endpoint, last, wait)
                    time.sleep(wait)
                else:
                    log.warning("llm: %s %s", self.endpoint, last)
        proxied = (
            "connect",
            "tls-plain",
            "tls-cert",
            "dropped",
            "timeout",
            "status",
            "api",
            "decode",
        )
        raise HeuristicError(
            f"Heuristic 'llm': no usable reply from {self.endpoint} (model {self.model!r}) for "
            f"{query!r} after {attempts} attempt(s); last: {last}. "
            f"{failure_fix(why, self.timeout, self.json_mode, self.base_url)}"
            f"{proxy_note(self.endpoint) if why in proxied else ''}"
        )

    def _warn_cleartext(self) -> None:
        """Once per host: the key goes over plain http to a host that is not this
        machine."""
        host = cleartext_host(self.endpoint)
        where = urlsplit(self.endpoint).netloc
        if host is None or where in _CLEARTEXT_WARNED:
            return
        _CLEARTEXT_WARNED.add(where)
        log.warning(
            "llm: base_url %s is plain http to %s, which is not this machine: the API key "
            "from %r (api_key_env) crosses the network unencrypted, readable by anyone on "
            "the way. Use https:// (or an SSH tunnel to 127.0.0.1).",
            self.base_url,
            host,
            self.api_key_env,
        )

    def _known_models(self, client: Any) -> tuple[str, list[str]]:
        """The server's models (:func:`known_models`), asked with this endpoint's
        headers and query, and at most 5 s."""
        return known_models(
            client,
            self.endpoint,
            self._headers(),
            min(self.timeout, 5.0),
            urlsplit(self._url).query,
        )

    def _status_hint(self, status: int, client: Any, body: str = "") -> str:
        """What to do about a status that is not retried (401, 403, 404, 400...);
        ``body``: the server's reply, which a 400 about the model is told by."""
        if status in (401, 403):
            if self.api_key_env:
                return f" Check the API key in {self.api_key_env!r} (api_key_env)."
            return (
                " The server wants a key: set api_key_env to the name of the environment "
                "variable that holds it (no key was sent)."
            )
        if status == 404:
            base, models = self._known_models(client)
            return not_found_hint(self.endpoint, self.model, base, models)
        if status in (400, 422) and "model" in body.lower():
            # LiteLLM, some gateways and older vLLM answer an unknown model with a 400
            base, models = self._known_models(client)
            if models and self.model not in models:
                return not_found_hint(self.endpoint, self.model, base, models)
        if status in (400, 422) and self.json_mode:
            return (
                " json_mode: true sends response_format, which this server may not support: "
                "set json_mode: false (replies are parsed anyway)."
            )
        return ""
