"""Loading the word lists that heuristics ship with or read from the user."""

from __future__ import annotations

from importlib import resources
from pathlib import Path
from typing import Any

from ..core.errors import ConfigError


def read_word_list(
    spec: str | list[str] | None, default: str, what: str, *, option: str = ""
) -> list[str]:
    """Names from ``spec``: None for the shipped ``default`` file, a list, or a path.

    Text files hold one entry per line; blank lines and lines starting with ``#`` are
    skipped; duplicates are dropped (first kept). YAML files hold a list. ``option``: a
    sentence naming the option that names the file and what to give it, said when the
    file is missing.
    """
    if spec is None or spec == "default":
        text = resources.files("quash_plugins.data").joinpath(default).read_text(encoding="utf-8")
        items = _lines(text)
        where = f"the shipped {default}"
    elif isinstance(spec, (list, tuple)):
        items = [" ".join(str(s).split()) for s in spec]
        where = f"the {what} list"
    else:
        path = Path(str(spec)).expanduser()
        where = str(path)
        if not path.exists():
            raise _not_found(path, what, option, (".txt", ".yaml", ".yml"))
        if path.suffix in (".yaml", ".yml"):
            from ..core.yaml_files import load_yaml

            data, _ = load_yaml(path)
            if not isinstance(data, list):
                raise ConfigError(f"{path}: expected a YAML list of {what} entries.")
            items = [" ".join(str(s).split()) for s in data]
        else:
            from ..core.yaml_files import read_text_file

            items = _lines(read_text_file(path, f"{what} file"))
    items = list(dict.fromkeys(s for s in items if s))
    if not items:
        raise ConfigError(f"{where}: the {what} list is empty.")
    return items


def read_mapping(
    spec: str | dict[str, Any] | None,
    default: str | None,
    what: str,
    *,
    form: tuple[str, str] | None = None,
    option: str = "",
) -> dict:
    """A YAML mapping from ``spec`` (path, dict) or the shipped ``default`` file.

    ``form``: what a key and an item of its list are (``("label", "sub-class")``): a file
    that is not a mapping is answered with the form, and a list with an example built
    from its own first entries. ``option``: a sentence naming the option that names the
    file and what to give it, said when the file is missing.
    """
    from ..core.yaml_files import load_yaml, load_yaml_text

    if isinstance(spec, dict):
        return dict(spec)
    if spec is None:
        if default is None:
            raise ConfigError(f"No {what} given.")
        text = resources.files("quash_plugins.data").joinpath(default).read_text(encoding="utf-8")
        return load_yaml_text(text, default)
    path = Path(str(spec)).expanduser()
    if not path.exists():
        raise _not_found(path, what, option, (".yaml", ".yml", ".json"))
    data, _ = load_yaml(path)
    if not isinstance(data, dict):
        raise ConfigError(_not_a_mapping(path, data, what, form))
    return data


def _not_a_mapping(path: Path, data: Any, what: str, form: tuple[str, str] | None) -> str:
    """``path`` holds ``data``, not a mapping: the form expected and, for a list, the
    form written with its own first entries (``- chair`` -> ``chair: [SUB-CLASS, ...]``)."""
    if form is None:
        return f"{path}: expected a YAML mapping for the {what}."
    key, item = form
    message = f"{path}: expected a YAML mapping {{{key}: [{item}, ...]}} for the {what}"
    names = [
        str(next(iter(e))) if isinstance(e, dict) and len(e) == 1 else " ".join(str(e).split())
        for e in (data if isinstance(data, list) else [])
        if isinstance(e, (str, int, float)) or (isinstance(e, dict) and len(e) == 1)
    ]
    if not isinstance(data, list) or len(names) < len(data) or not names:
        got = "an empty file" if data is None else f"a {type(data).__name__}"
        return f"{message}; got {got}" + (f", {data!r}." if isinstance(data, str) else ".")
    first, *rest = names
    second = f"\n  {rest[0]}: []" if rest else ""
    items = f"{item}es" if item.endswith("s") else f"{item}s"
    return (
        f"{message}; it holds a list of {len(names)} {key}s. Give each {key} as a key with "
        f"its list of {items} (an empty list: none), e.g.:\n  {first}: [{item.upper()}, ...]"
        f"{second}"
    )


def _not_found(
    path: Path, what: str, option: str = "", suffixes: tuple[str, ...] | None = None
) -> ConfigError:
    """A missing file, naming the folder a relative path was read from: the working
    directory, since a config given as a mapping (a dict, a section of a Hydra config)
    has no folder of its own (a YAML config's paths are made absolute from its folder);
    the files beside it with a near name, and the ``option`` that names it."""
    from ..core.errors import near_paths

    message = f"{what.capitalize()} file not found: {path}"
    if not path.is_absolute():
        message += (
            f" (a relative path is read from the working directory, {Path.cwd()}; a config "
            "given as a mapping has no folder of its own: give an absolute path)"
        )
    near = near_paths(path, suffixes)
    message += f". Did you mean {' or '.join(near)}?" if near else "."
    return ConfigError(f"{message} {option}".rstrip())


def _lines(text: str) -> list[str]:
    out = []
    for line in text.splitlines():
        line = line.split("#", 1)[0].strip() if not line.lstrip().startswith("#") else ""
        if line:
            out.append(" ".join(line.split()))
    return out
