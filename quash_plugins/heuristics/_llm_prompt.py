"""What the ``llm`` heuristic asks: the prompt (:data:`SYSTEM_PROMPT`,
:data:`USER_PROMPT`, versioned by :data:`PROMPT_VERSION`, which is part of every cache
key) and the chat-completions request built from it (:func:`chat_request`)."""

from __future__ import annotations

from typing import Any

__all__ = ["PROMPT_VERSION", "SYSTEM_PROMPT", "USER_PROMPT", "chat_request"]

#: Bumped whenever the prompt wording changes; part of every cache key.
PROMPT_VERSION = "quash-llm-2"

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


def chat_request(
    query: str,
    *,
    model: str,
    n_synonyms: int,
    n_antonyms: int,
    temperature: float,
    json_mode: bool,
    seed: int | None = None,
) -> dict[str, Any]:
    """The chat-completions request body asking ``model`` about ``query``: the seed is
    sent when given, ``response_format`` when ``json_mode``."""
    user = USER_PROMPT.format(query=query, n_synonyms=n_synonyms, n_antonyms=n_antonyms)
    body: dict[str, Any] = {
        "model": model,
        "messages": [
            {"role": "system", "content": SYSTEM_PROMPT},
            {"role": "user", "content": user},
        ],
        "temperature": temperature,
    }
    if json_mode:
        body["response_format"] = {"type": "json_object"}
    if seed is not None:
        body["seed"] = int(seed)
    return body
