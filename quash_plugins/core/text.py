"""Text encoding shared by the engine and by plugins: the cache protocol and prompt templates."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from importlib import resources
from pathlib import Path
from typing import Any, NamedTuple, Protocol

import numpy as np

from .errors import (
    ConfigError,
    EncoderError,
    QuashError,
    closest,
    install_hint,
    missing_module,
)
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


def _origin(encoder: Encoder) -> str:
    """Where ``encoder``'s class comes from, for messages: its module and, when installed
    by one, its distribution (``acme.enc, distribution acme-encoders==0.1``)."""
    dist = distribution_of(type(encoder).__module__)
    return type(encoder).__module__ + (f", distribution {dist}" if dist else "")


def encoder_dim(encoder: Encoder) -> int:
    """``encoder.dim`` as a positive int; a plugin whose ``dim`` raises (a lazy model not
    loaded yet) or is no positive whole number is an :class:`EncoderError` naming the
    encoder, its module and distribution, not an anonymous crash."""
    try:
        value = encoder.dim
        dim = int(value)
        ok = dim > 0 and dim == value
    except QuashError:
        raise
    except Exception as exc:  # noqa: BLE001 - named with the encoder that raised it
        value, ok, error = None, False, f"{type(exc).__name__}: {str(exc).rstrip('.')}"
    else:
        error = f"it is {value!r}, not a positive whole number"
    if ok:
        return dim
    raise EncoderError(
        f"Encoder {plugin_name(encoder)!r} ({_origin(encoder)}) cannot give its embedding dimension "
        f"'dim' ({error}). dim must be readable before any text is encoded: set it in "
        "__init__ or compute it without the model (docs/plugins.md)."
    ) from None


def encode_texts(
    encoder: Encoder, texts: Sequence[str], cache: TextCache | None = None
) -> np.ndarray:
    """Embed ``texts`` with ``encoder``, serving what it can from ``cache``.

    Returns ``(len(texts), encoder.dim)`` float32, unit-norm rows. Only strings missing
    from the cache reach the model, each once.
    """
    texts = list(texts)
    dim = encoder_dim(encoder)
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
                # a third party's distribution must list it (a built-in's: an extra)
                dist = distribution_of(type(encoder).__module__)
                ours = type(encoder).__module__.startswith("quash_plugins.")
                raise EncoderError(
                    f"Encoder {plugin_name(encoder)!r} ({_origin(encoder)}) failed to encode "
                    f"({type(exc).__name__}: {exc}): it "
                    + install_hint(module, None if ours or not dist else dist.partition("==")[0])
                ) from exc
            raise EncoderError(
                f"Encoder {plugin_name(encoder)!r} ({_origin(encoder)}) failed to encode "
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
            origin=_origin(encoder),
        )
        new = dict(zip(missing, emb))
        found.update(new)
        if cache is not None and fp is not None:
            cache.store(fp, new)
    return np.stack([found[t] for t in texts]).astype(np.float32, copy=False)


#: ``templates: vlmaps``: VLMaps' own prompt templates, from the user's installed VLMaps;
#: without one, our default list with a warning (the rule is then not VLMaps' exactly).
VLMAPS_TEMPLATES = "vlmaps"
#: ``templates: vlmaps-or-default``: VLMaps' own list when VLMaps is installed, else our
#: default list, said at INFO and never warned. The name reads as its two outcomes, each
#: itself a template name. It is for configs run where VLMaps is not expected to be
#: installed (the shipped demo peers that ``quash demo``, ``quash eval`` and the
#: benchmarks run), where the stand-in is the expected case, not a mistake to warn about.
VLMAPS_OR_DEFAULT = "vlmaps-or-default"
#: The template lists a ``templates`` setting may name; any other string is a file.
TEMPLATE_NAMES = ("default", VLMAPS_TEMPLATES, VLMAPS_OR_DEFAULT)
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

    from .yaml_files import read_text_file

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


class Templates(NamedTuple):
    """Resolved prompt templates and, in words, where they came from (for provenance)."""

    templates: list[str]
    source: str


class TemplateList(list):
    """A resolved template list that remembers where it came from (``source``): handed
    on as a ``templates`` setting (the ``templates`` heuristic's), the provenance of the
    pipeline that adopts it still says where the list came from."""

    def __init__(self, templates: Sequence[str], source: str) -> None:
        super().__init__(templates)
        self.source = source


def load_templates(spec: Any) -> list[str]:
    """Resolve a ``templates`` setting to its list (see :func:`resolve_templates`)."""
    return resolve_templates(spec).templates


def resolve_templates(spec: Any) -> Templates:
    """Resolve a ``templates`` setting: the list and where it came from.

    ``"default"`` (our list); ``"vlmaps"`` (VLMaps' own list from the installed
    ``vlmaps`` package, see :func:`vlmaps_templates_file`; our list with a warning when
    VLMaps is not installed); ``"vlmaps-or-default"`` (the same, but without VLMaps our
    list is said at INFO, not warned); a list; or a file: ``.txt`` (one per line),
    ``.yaml`` (a list) or ``.py`` (its module-level ``multiple_templates`` list, e.g.
    VLMaps' ``clip_utils.py`` in a clone that is not installed).

    Examples
    --------
    >>> resolve_templates("default").source
    'our default list'
    >>> resolve_templates(["a {}.", "the {}."])
    Templates(templates=['a {}.', 'the {}.'], source='a list of 2 in the config')
    """
    if spec in (VLMAPS_TEMPLATES, VLMAPS_OR_DEFAULT):
        found = vlmaps_templates_file()
        if found is not None:
            return Templates(
                _checked_templates(read_vlmaps_templates(found)), f"VLMaps' list ({found})"
            )
        _say_no_vlmaps(spec)
        return Templates(_default_templates(), f"our default list ({spec}: no VLMaps installed)")
    if spec is None or spec == "default":
        return Templates(_default_templates(), "our default list")
    if isinstance(spec, (list, tuple)):
        templates = [str(t) for t in spec]
        source = getattr(spec, "source", None) or f"a list of {len(templates)} in the config"
        return Templates(_checked_lines(templates), source)
    path = Path(str(spec)).expanduser()
    if not path.exists():
        raise ConfigError(
            misspelt_template_name(path)
            or f"Prompt-template file not found: {path} (prompt_templates: templates:). Fix "
            f"the path, or name one of the template lists: {', '.join(TEMPLATE_NAMES)}."
        )
    if path.suffix == ".py":
        return Templates(_checked_templates(read_vlmaps_templates(path)), str(path))
    if path.suffix in (".yaml", ".yml"):
        from .yaml_files import load_yaml

        data, _ = load_yaml(path)
        if not isinstance(data, list):
            raise ConfigError(f"{path}: expected a YAML list of templates with '{{}}'.")
        return Templates(_checked_lines([str(t) for t in data]), str(path))
    from .yaml_files import read_text_file

    text = read_text_file(path, "prompt-template file")
    return Templates(_checked_lines([ln.strip() for ln in text.splitlines()]), str(path))


def misspelt_template_name(path: str | Path) -> str | None:
    """The error for a ``templates`` setting that reads as a template name, not a file
    (no suffix, no such file: ``vlmaps-or-defualt``), naming the known ones; else None."""
    path = Path(path).expanduser()
    if path.suffix or path.exists():
        return None
    near = closest(path.name, TEMPLATE_NAMES)
    return (
        f"prompt_templates: templates: {path.name!r} is not a template list "
        f"({', '.join(TEMPLATE_NAMES)}) and there is no such file ({path})."
        + (f" Did you mean {near!r}?" if near else "")
        + " Name one of the lists, or give a .txt, .yaml or .py file of templates."
    )


def _say_no_vlmaps(spec: str) -> None:
    """Without VLMaps, ``vlmaps`` warns (once per process, then INFO: a benchmark builds
    the VLMaps configs for every scene); ``vlmaps-or-default`` says it at INFO (once,
    then DEBUG)."""
    first = first_time(("no-vlmaps", spec))
    if spec == VLMAPS_TEMPLATES:
        log.log(
            logging.WARNING if first else logging.INFO,
            "templates: vlmaps: no installed VLMaps package was found (vlmaps/utils/"
            "clip_utils.py), so the default templates are used and the rule is not VLMaps' "
            "exactly. Install VLMaps from its clone (pip install -e .), or set templates: "
            "to VLMaps' clip_utils.py or to a file with one template per line (or to "
            f"{VLMAPS_OR_DEFAULT} to take the default ones without this warning).",
        )
        return
    log.log(
        logging.INFO if first else logging.DEBUG,
        f"templates: {spec}: no installed VLMaps package was found (vlmaps/utils/"
        "clip_utils.py), so our default prompt templates are used, not VLMaps' own.",
    )


def _default_templates() -> list[str]:
    text = (
        resources.files("quash_plugins.data")
        .joinpath("prompt_templates.txt")
        .read_text(encoding="utf-8")
    )
    return _checked_lines([ln.strip() for ln in text.splitlines()])


def _checked_lines(templates: list[str]) -> list[str]:
    """``templates`` without blank and ``#`` comment lines, checked."""
    return _checked_templates([t for t in templates if t and not t.startswith("#")])


def _checked_templates(templates: list[str]) -> list[str]:
    bad = [t for t in templates if t.count("{}") != 1]
    if bad:
        raise ConfigError(f"Prompt template {bad[0]!r} must contain exactly one '{{}}'.")
    if not templates:
        raise ConfigError("The prompt-template list is empty.")
    return templates


def label_key(name: str) -> str:
    """A label name as a query's label is matched to a map's names, and an evaluation's
    excluded names to them: case, spacing and underscores ignored.

    >>> label_key("TV_Monitor")
    'tv monitor'
    """
    return " ".join(str(name).replace("_", " ").split()).casefold()


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
