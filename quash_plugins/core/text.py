"""Text encoding shared by the engine and by plugins: the cache protocol and prompt templates."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from importlib import resources
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from .errors import ConfigError, EncoderError, QuashError, install_hint, missing_module
from .interfaces import Encoder, check_text_embeddings, plugin_name
from .once import first_time
from .registry import distribution_of

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
        log.debug("encoding %d new strings with %s", len(missing), plugin_name(encoder))
        try:
            raw = encoder.encode_text(missing)
        except QuashError:
            raise
        except Exception as exc:  # noqa: BLE001 - named with the encoder that raised it
            module = missing_module(exc)
            if module is not None:  # a plugin importing its model library on first use
                raise EncoderError(
                    f"Encoder {plugin_name(encoder)!r} ({type(encoder).__module__}) failed to encode "
                    f"({type(exc).__name__}: {exc}): it {install_hint(module)}"
                ) from exc
            dist = distribution_of(type(encoder).__module__)
            raise EncoderError(
                f"Encoder {plugin_name(encoder)!r} ({type(encoder).__module__}"
                f"{f', distribution {dist}' if dist else ''}) failed to encode "
                f"{len(missing)} strings: {type(exc).__name__}: {str(exc).rstrip('.')}. "
                "Fix the encoder or its parameters (the config's 'encoder:' section); "
                "--debug shows the traceback."
            ) from exc
        emb = check_text_embeddings(
            raw,
            missing,
            dim,
            plugin_name(encoder),
            warn_norm=getattr(encoder, "normalize", True) is not False,
        )
        new = dict(zip(missing, emb))
        found.update(new)
        if cache is not None and fp is not None:
            cache.store(fp, new)
    return np.stack([found[t] for t in texts]).astype(np.float32, copy=False)


#: ``templates: vlmaps``: VLMaps' own prompt templates, from the user's installed VLMaps.
VLMAPS_TEMPLATES = "vlmaps"
#: The module-level list that holds them in ``vlmaps/utils/clip_utils.py``.
VLMAPS_TEMPLATES_VARIABLE = "multiple_templates"


def vlmaps_templates_file() -> Path | None:
    """``vlmaps/utils/clip_utils.py`` of the user's installed VLMaps, or None.

    Found with :func:`importlib.util.find_spec` on the top-level ``vlmaps`` package, which
    locates it without importing it (importing ``clip_utils`` would pull in torch, CLIP
    and OpenCV). VLMaps' ``utils`` folder has no ``__init__.py``; the file is looked up in
    every search location of the package.
    """
    import importlib.util

    try:
        spec = importlib.util.find_spec(VLMAPS_TEMPLATES)
    except (ImportError, ValueError):
        return None
    if spec is None:
        return None
    for location in spec.submodule_search_locations or []:
        candidate = Path(location) / "utils" / "clip_utils.py"
        if candidate.is_file():
            return candidate
    return None


def read_vlmaps_templates(path: str | Path) -> list[str]:
    """The list assigned to ``multiple_templates`` at module level in ``path``, read with
    :mod:`ast` (the file is parsed, never executed)."""
    import ast

    from .config import read_text_file

    path = Path(path)
    text = read_text_file(path, "prompt-template file")
    try:
        tree = ast.parse(text, filename=str(path))
    except (SyntaxError, ValueError) as exc:
        raise ConfigError(f"{path}: cannot parse the prompt templates ({exc}).") from None
    value: Any = None
    for node in tree.body:
        if isinstance(node, ast.Assign):
            targets, expr = node.targets, node.value
        elif isinstance(node, ast.AnnAssign) and node.value is not None:
            targets, expr = [node.target], node.value
        else:
            continue
        if any(isinstance(t, ast.Name) and t.id == VLMAPS_TEMPLATES_VARIABLE for t in targets):
            try:
                value = ast.literal_eval(expr)  # the last assignment wins, as in Python
            except ValueError:
                raise ConfigError(
                    f"{path}: {VLMAPS_TEMPLATES_VARIABLE!r} is not a literal list of strings."
                ) from None
    if not isinstance(value, (list, tuple)) or not all(isinstance(t, str) for t in value):
        raise ConfigError(
            f"{path}: no module-level list of strings named {VLMAPS_TEMPLATES_VARIABLE!r} "
            "(VLMaps keeps its prompt templates there in vlmaps/utils/clip_utils.py)."
        )
    return list(value)


def load_templates(spec: Any) -> list[str]:
    """Resolve a ``templates`` setting.

    ``"default"`` (our list), ``"vlmaps"`` (VLMaps' own list from the installed ``vlmaps``
    package, see :func:`vlmaps_templates_file`; our list with a warning when VLMaps is
    not installed), a list, or a file: ``.txt`` (one per line), ``.yaml`` (a list) or
    ``.py`` (its module-level ``multiple_templates`` list, e.g. VLMaps' ``clip_utils.py``
    in a clone that is not installed).
    """
    if spec == VLMAPS_TEMPLATES:
        found = vlmaps_templates_file()
        if found is not None:
            return _checked_templates(read_vlmaps_templates(found))
        # Once per process: a benchmark builds the VLMaps configs for every scene.
        log.log(
            logging.WARNING if first_time(("no-vlmaps",)) else logging.INFO,
            "templates: vlmaps: no installed VLMaps package was found (vlmaps/utils/"
            "clip_utils.py), so the default templates are used and the rule is not VLMaps' "
            "exactly. Install VLMaps from its clone (pip install -e .), or set templates: "
            "to VLMaps' clip_utils.py or to a file with one template per line.",
        )
        spec = "default"
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
        path = Path(str(spec)).expanduser()
        if not path.exists():
            raise ConfigError(f"Prompt-template file not found: {path}")
        if path.suffix == ".py":
            return _checked_templates(read_vlmaps_templates(path))
        if path.suffix in (".yaml", ".yml"):
            from .config import load_yaml

            data, _ = load_yaml(path)
            if not isinstance(data, list):
                raise ConfigError(f"{path}: expected a YAML list of templates with '{{}}'.")
            templates = [str(t) for t in data]
        else:
            from .config import read_text_file

            text = read_text_file(path, "prompt-template file")
            templates = [ln.strip() for ln in text.splitlines()]
    return _checked_templates([t for t in templates if t and not t.startswith("#")])


def _checked_templates(templates: list[str]) -> list[str]:
    bad = [t for t in templates if t.count("{}") != 1]
    if bad:
        raise ConfigError(f"Prompt template {bad[0]!r} must contain exactly one '{{}}'.")
    if not templates:
        raise ConfigError("The prompt-template list is empty.")
    return templates


def head_index(words: Sequence[str]) -> int:
    """The position of a noun phrase's head noun: the word before "of", else the last.

    ``words`` is the phrase split on spaces (not empty). The taxonomy heuristic
    singularises this word to match names; the demo scene pluralises it.

    Examples
    --------
    >>> head_index(["chest", "of", "drawers"]), head_index(["bunk", "bed"])
    (0, 1)
    """
    return words.index("of", 1) - 1 if "of" in words[1:] else len(words) - 1
