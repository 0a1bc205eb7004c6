"""``llm`` heuristic: synonyms and antonyms from any OpenAI-compatible chat endpoint.

Works with hosted APIs and with local vLLM, Ollama (``/v1``) and llama.cpp servers: all
of them speak ``POST {base_url}/chat/completions``. Query sets are cached on disk, so an
experiment can be re-run with ``offline: true`` and no server at all.
"""

from __future__ import annotations

import logging
from datetime import UTC, datetime
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from ..core.errors import HeuristicError
from ..core.interfaces import ExpansionContext, Heuristic
from ..core.redact import RedactingFilter, redact_url, url_secrets
from ..core.types import QuerySet
from ._llm_cache import (
    cache_file_name,
    llm_cache_root,
    offline_miss,
    read_query_set,
    write_query_set,
)
from ._llm_endpoint import (
    chat_endpoint,
    check_config,
    check_key_env,
    request_headers,
    request_url,
)
from ._llm_http import bounded_request, cleartext_host, client_options, known_models
from ._llm_prompt import PROMPT_VERSION, SYSTEM_PROMPT, USER_PROMPT, chat_request
from ._llm_retry import RETRY_STATUSES, ask_with_retries, status_hint
from ._parse import clean_lists

# The prompt and the retried statuses, long defined here, are still importable from here.
__all__ = [
    "LLM_DEFAULT_BASE_URL",
    "PROMPT_VERSION",
    "RETRY_STATUSES",
    "SYSTEM_PROMPT",
    "USER_PROMPT",
    "LLMHeuristic",
    "chat_endpoint",
]

log = logging.getLogger(__name__)
# Whoever configures logging, nothing this module logs carries a key-like token.
log.addFilter(RedactingFilter())
# httpx logs each request's URL at INFO, query string included (base_url's ?key=...): the
# values of credential-like parameters are masked there too.
_httpx_log = logging.getLogger("httpx")
if not any(isinstance(f, RedactingFilter) for f in _httpx_log.filters):
    _httpx_log.addFilter(RedactingFilter())

#: The endpoint asked when a config gives no ``base_url`` (vLLM's default port).
LLM_DEFAULT_BASE_URL = "http://127.0.0.1:8000/v1"

#: Hosts warned about once: an http:// endpoint elsewhere that is sent the key.
_CLEARTEXT_WARNED: set[str] = set()


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
        check_config(
            model,
            n_synonyms=n_synonyms,
            n_antonyms=n_antonyms,
            max_retries=max_retries,
            timeout=timeout,
        )
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
        key = self.cache_key(query, seed)
        data = read_query_set(self.cache_path(query, seed), key, log.warning)
        if data is None:
            return None
        # a file edited by hand is cleaned as a reply is (case, duplicates, the query, caps)
        lists = (data["synonyms"], data["antonyms"])
        syn, ant = clean_lists(query, *lists, self.n_synonyms, self.n_antonyms)
        return {**data, "synonyms": syn, "antonyms": ant}

    def _write_cache(
        self, query: str, synonyms: list[str], antonyms: list[str], seed: int | None = None
    ) -> Path | None:
        """Cache a query set; its file, or None (with a warning) when it cannot be written."""
        record = {
            "key": self.cache_key(query, seed),
            "synonyms": synonyms,
            "antonyms": antonyms,
            "temperature": self.temperature,
            "created": datetime.now(UTC).isoformat(timespec="seconds"),
        }
        return write_query_set(self.cache_path(query, seed), record, log.warning)

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
            raise offline_miss(self.cache_key(query, seed), where)
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
        return chat_request(
            query,
            model=self.model,
            n_synonyms=self.n_synonyms,
            n_antonyms=self.n_antonyms,
            temperature=self.temperature,
            json_mode=self.json_mode,
            seed=seed if self.send_seed else None,
        )

    def _headers(self) -> dict[str, str]:
        return request_headers(self.api_key_env)

    def ask(self, query: str, seed: int | None = None) -> tuple[list[str], list[str]]:
        """Call the server (with retries: :func:`ask_with_retries`) and return cleaned
        ``(synonyms, antonyms)``.

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
        # one connection per request: bounded_request's deadline watches the sockets it
        # sees connected
        with httpx.Client(
            timeout=httpx.Timeout(self.timeout),
            limits=httpx.Limits(max_keepalive_connections=0),
            **client_options(self.endpoint),
        ) as client:
            return ask_with_retries(
                self,
                query,
                secrets,
                httpx=httpx,
                send=lambda: bounded_request(
                    client, "POST", self._url, json=body, headers=headers, timeout=self.timeout
                ),
                hint=lambda status, text: self._status_hint(status, client, text),
                log=log,
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

    def _status_hint(self, status: int, client: Any, body: str = "") -> str:
        """What to do about a status that is not retried (:func:`status_hint`); the
        server's models (:func:`known_models`) are asked with this endpoint's headers and
        query, and at most 5 s, when that helps."""
        return status_hint(
            status,
            body,
            endpoint=self.endpoint,
            model=self.model,
            api_key_env=self.api_key_env,
            json_mode=self.json_mode,
            known_models=lambda: known_models(
                client,
                self.endpoint,
                self._headers(),
                min(self.timeout, 5.0),
                urlsplit(self._url).query,
            ),
        )
