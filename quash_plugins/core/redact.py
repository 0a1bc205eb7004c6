"""Keep secrets out of messages, logs and files.

:func:`redact` replaces what looks like a credential with ``***``: the exact values
given (an API key read from the environment), API-key-like tokens (``sk-...``,
``hf_...``, ``AIza...``), ``Bearer`` tokens, ``key=value`` pairs named like secrets,
and the user-info part of URLs (``https://user:password@host``). :class:`RedactingFilter`
applies it to every log record that passes through a logger or handler.

Examples
--------
>>> redact("Incorrect API key provided: sk-proj-abc123def456")
'Incorrect API key provided: ***'
>>> redact("http://me:hunter22@127.0.0.1:8000/v1")
'http://***@127.0.0.1:8000/v1'
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
_USERINFO = re.compile(r"(?i)\b([a-z][a-z0-9+.\-]*://)[^/\s@]+@")


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
    out = _USERINFO.sub(rf"\1{MASK}@", out)
    out = _TOKENS.sub(MASK, out)
    out = _BEARER.sub(rf"\1 {MASK}", out)
    return _NAMED.sub(rf"\1{MASK}", out)


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
