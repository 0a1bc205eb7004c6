"""Keep secrets out of messages, logs and files.

:func:`redact` replaces what looks like a credential with ``***``: the exact values
given (an API key read from the environment), API-key-like tokens (``sk-...``,
``hf_...``, ``AIza...``), ``Bearer`` tokens, ``key=value`` pairs named like secrets,
the user-info part of URLs (``https://user:password@host``) and the values of query-string
parameters named like credentials (``?key=...``, ``&sig=...``, ``?code=...``).
:func:`redact_url` is for a URL shown to the user: it hides every query-string value, not
only those. :class:`RedactingFilter` applies :func:`redact` to every log record that
passes through a logger or handler.

Every pattern costs time linear in the text's length, so a server's reply of megabytes is
redacted in well under a second.

Examples
--------
>>> redact("Incorrect API key provided: sk-proj-abc123def456")
'Incorrect API key provided: ***'
>>> redact("http://me:hunter22@127.0.0.1:8000/v1")
'http://***@127.0.0.1:8000/v1'
>>> redact("https://host/v1?api-version=2024-02-01&key=AbC123xyz")
'https://host/v1?api-version=2024-02-01&key=***'
>>> redact_url("https://me:pw@host/v1?api-version=2024-02-01&key=AbC123xyz")
'https://***@host/v1?api-version=***&key=***'
"""

from __future__ import annotations

import logging
import re
from collections.abc import Iterable
from typing import Any

MASK = "***"
#: A secret this long is removed wherever it appears, even inside a longer word.
MIN_SUBSTRING_SECRET = 6
#: A shorter secret of at least this many characters is removed where it is a word.
MIN_WORD_SECRET = 3

_TOKENS = re.compile(
    r"\b(?:sk|pk|rk)-[A-Za-z0-9_\-*.]{6,}"  # OpenAI-style keys, also masked echoes
    r"|\bhf_[A-Za-z0-9]{8,}"  # Hugging Face tokens
    r"|\bAIza[0-9A-Za-z_\-]{20,}"  # Google API keys
)
# A token holds a digit, a capital or a symbol: "Basic dXNlcjpwYXNz" is one, "basic armchair"
# (an object an LLM names, a query) is not.
_BEARER = re.compile(
    r"(?i)\b(bearer|basic)\s+(?-i:(?=[a-z]*[A-Z0-9_\-.~+/=*]))[A-Za-z0-9_\-.~+/=*]{6,}"
)
_NAMED = re.compile(
    r"(?i)\b((?:api[_-]?key|access[_-]?token|auth[_-]?token|token|secret|password|passwd)"
    r"[\"']?\s*[:=]\s*[\"']?)[^\s\"',;&}]{4,}"
)
# The user-info of a URL: found from its "://" (a pattern that began with the scheme was
# tried at every word start and rescanned the rest of the text from each: "a.a.a.a..." of
# 100 kB took a minute), then checked for a scheme of at most 32 characters before it.
_USERINFO = re.compile(r"://[^/\s@]+@")
_SCHEME_TAIL = re.compile(r"(?i)[a-z][a-z0-9+.\-]{0,31}\Z")
#: A query-string parameter: its name (at most 64 characters, so that a "?" followed by a
#: long word costs nothing) and its value (up to the next "&", "#", "?" or white space).
_QUERY_PARAM = re.compile(r"([?&])([\w.~%\-\[\]]{1,64})=([^\s&#?'\"<>]+)")
#: A parameter name that marks its value as a credential (``key``, ``api-key``,
#: ``access_token``, ``sig``, ``X-Amz-Signature``, ``code``, ``client_secret``...).
_SECRET_NAME = re.compile(
    r"(?i)key|token|secret|sig|code|pass|pwd|auth|credential|session|jwt|bearer"
)


def redact(text: Any, secrets: Iterable[str | None] = ()) -> str:
    """``text`` as a string with every credential it holds replaced by ``***``.

    Parameters
    ----------
    text
        Anything; converted with ``str``.
    secrets
        Exact values to remove: wherever they appear when 6 characters or longer; a
        shorter one (a local server's ``EMPTY`` or ``abc``) where it stands as a word of
        its own, not inside another word (so that a key ``abc`` leaves "cabcase" alone);
        one of 1 or 2 characters is ignored, so that it cannot blank a message.
    """
    out = str(text)
    for secret in secrets:
        if not secret or len(secret) < MIN_WORD_SECRET:
            continue
        if len(secret) >= MIN_SUBSTRING_SECRET:
            out = out.replace(secret, MASK)
        else:
            word = rf"(?<![A-Za-z0-9]){re.escape(secret)}(?![A-Za-z0-9])"
            out = re.sub(word, MASK, out)
    out = _mask_userinfo(out)
    out = _QUERY_PARAM.sub(_mask_secret_param, out)
    out = _TOKENS.sub(MASK, out)
    out = _BEARER.sub(rf"\1 {MASK}", out)
    return _NAMED.sub(rf"\1{MASK}", out)


def redact_start(text: Any, secrets: Iterable[str | None] = (), n: int = 160) -> str:
    """The first ``n`` characters of ``text`` for a message, quoted, white space collapsed,
    with ``...`` when there is more: redacted *before* it is shortened (a key cut in two
    no longer matches itself, and its first part would show).

    Only a window of the start is redacted (cut at white space where it can be), grown
    until the redacted text is safely longer than ``n``: a secret that crosses the
    window's end lies past the part kept. A reply of megabytes costs no more than a short
    one.

    >>> redact_start("see sk-proj-abc123def456 " + "x" * 200, n=12)
    "'see *** xxxx...'"
    """
    text = str(text)
    longest = max((len(s) for s in secrets if s), default=0)
    margin = max(256, 2 * longest + 64)
    window = 4 * n + margin
    while True:
        part = text[:window]
        if window < len(text):
            cut = max(part.rfind(c) for c in " \t\r\n")
            if cut > window // 2:
                part = part[:cut]
        out = " ".join(redact(part, secrets).split())
        if window >= len(text) or len(out) >= n + margin:
            break
        window *= 4
    return repr(out[:n] + "..." if len(out) > n else out)


def _mask_userinfo(text: str) -> str:
    def mask(match: re.Match) -> str:
        if _SCHEME_TAIL.search(text, max(0, match.start() - 32), match.start()):
            return f"://{MASK}@"
        return match.group(0)

    return _USERINFO.sub(mask, text)


def _mask_secret_param(match: re.Match) -> str:
    if not _SECRET_NAME.search(match.group(2)):
        return match.group(0)
    return f"{match.group(1)}{match.group(2)}={MASK}"


def is_secret_param(name: str) -> bool:
    """True when a query-string parameter named ``name`` looks like it carries a
    credential (``key``, ``api-key``, ``token``, ``sig``, ``code``, ``password``...)."""
    return bool(_SECRET_NAME.search(name))


def redact_url(url: Any, secrets: Iterable[str | None] = ()) -> str:
    """``url`` fit to show: :func:`redact` (user-info hidden), and every value of its
    query string and its fragment replaced by ``***``, whatever the name.

    A query string may carry a credential under any name (``?key=``, ``?code=``,
    ``?sig=``, a bare ``?AIza...``), so none of its values is shown; the names are kept,
    so that the URL still says what it holds.

    >>> redact_url("http://u:pw@h:8000/v1?key=S3cret&api-version=2024-02-01#frag")
    'http://***@h:8000/v1?key=***&api-version=***#***'
    """
    text = str(url)
    head, sep, query = text.partition("?")
    fragment = ""
    if sep:
        query, hashed, rest = query.partition("#")
        fragment = f"#{MASK}" if hashed and rest else hashed
    else:
        head, hashed, rest = head.partition("#")
        fragment = f"#{MASK}" if hashed and rest else hashed
    if sep:
        parts = []
        for part in query.split("&"):
            name, eq, value = part.partition("=")
            if eq:
                parts.append(f"{name}={MASK if value else ''}")
            else:
                parts.append(MASK if name else "")
        query = "&".join(parts)
    return redact(f"{head}{sep}{query}{fragment}", secrets)


def url_secrets(url: Any) -> list[str]:
    """The values of ``url``'s query-string parameters named like credentials (see
    :func:`is_secret_param`): secrets to pass to :func:`redact` for text that may quote
    the URL."""
    query = str(url).partition("?")[2].partition("#")[0]
    out = []
    for part in query.split("&"):
        name, eq, value = part.partition("=")
        if eq and value and is_secret_param(name):
            out.append(value)
    return out


class RedactingFilter(logging.Filter):
    """A logging filter that passes every record through :func:`redact`.

    The message is formatted with its arguments first, so a secret passed as an
    argument is caught too.
    """

    def __init__(self, secrets: Iterable[str] = ()) -> None:
        super().__init__()
        self.secrets = list(secrets)

    def filter(self, record: logging.LogRecord) -> bool:
        try:
            message = record.getMessage()
        except Exception:  # noqa: BLE001 - a bad format string is logging's business
            return True
        clean = redact(message, self.secrets)
        if clean != message:
            record.msg, record.args = clean, None
        return True
