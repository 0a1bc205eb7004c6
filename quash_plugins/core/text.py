"""Text encoding shared by the engine and by plugins: the cache protocol and prompt templates."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from importlib import resources
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from .errors import ConfigError
from .interfaces import Encoder, check_text_embeddings

log = logging.getLogger(__name__)

TEMPLATE_MODES = ("mean", "all")

#: A negative spelled like this is the zero vector, not a word (the paper's ablation).
ZERO_TOKEN = "<zero>"


class TextCache(Protocol):
    """What the pipeline needs from a text-embedding cache."""

    def lookup(self, fingerprint: str, texts: Sequence[str]) -> dict[str, np.ndarray]: ...

    def store(self, fingerprint: str, embeddings: dict[str, np.ndarray]) -> None: ...


def encode_texts(
    encoder: Encoder, texts: Sequence[str], cache: TextCache | None = None
) -> np.ndarray:
    """Embed ``texts`` with ``encoder``, serving what it can from ``cache``.

    Returns ``(len(texts), encoder.dim)`` float32, unit-norm rows. Only strings missing
    from the cache reach the model, each once.
    """
    texts = list(texts)
    dim = int(encoder.dim)
    if not texts:
        return np.zeros((0, dim), dtype=np.float32)
    found: dict[str, np.ndarray] = {}
    fp = None
    if cache is not None:
        fp = encoder.fingerprint()
        found = cache.lookup(fp, texts)
    missing = list(dict.fromkeys(t for t in texts if t not in found))
    if missing:
        log.debug("encoding %d new strings with %s", len(missing), encoder.name)
        emb = check_text_embeddings(encoder.encode_text(missing), missing, dim, encoder.name)
        new = dict(zip(missing, emb))
        found.update(new)
        if cache is not None and fp is not None:
            cache.store(fp, new)
    return np.stack([found[t] for t in texts]).astype(np.float32, copy=False)


def load_templates(spec: Any) -> list[str]:
    """Resolve a ``templates`` setting: ``"default"``, a list, or a text/YAML file path."""
    if spec is None or spec == "default":
        text = (
            resources.files("quash_plugins.data")
            .joinpath("prompt_templates.txt")
            .read_text(encoding="utf-8")
        )
        templates = [ln.strip() for ln in text.splitlines()]
    elif isinstance(spec, (list, tuple)):
        templates = [str(t) for t in spec]
    else:
        path = Path(str(spec))
        if not path.exists():
            raise ConfigError(f"Prompt-template file not found: {path}")
        if path.suffix in (".yaml", ".yml"):
            import yaml

            data = yaml.safe_load(path.read_text(encoding="utf-8"))
            if not isinstance(data, list):
                raise ConfigError(f"{path}: expected a YAML list of templates with '{{}}'.")
            templates = [str(t) for t in data]
        else:
            templates = [ln.strip() for ln in path.read_text(encoding="utf-8").splitlines()]
    templates = [t for t in templates if t and not t.startswith("#")]
    bad = [t for t in templates if t.count("{}") != 1]
    if bad:
        raise ConfigError(f"Prompt template {bad[0]!r} must contain exactly one '{{}}'.")
    if not templates:
        raise ConfigError("The prompt-template list is empty.")
    return templates
