"""Safe readers of the files a user hands in: :func:`read_text_file` (a regular UTF-8
file only: never a pipe or a device), :func:`load_yaml` and :func:`load_yaml_text`
(PyYAML's safe loader, with every duplicate key refused, the expansion of aliases
bounded, and the line of every key kept for error messages).

Configs, query files, taxonomies, word lists, prompt templates and class tables are all
read here, so each of them refuses the same bad input with the same words.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from .errors import ConfigError

#: How many nodes aliases (``*name``) may add to a YAML document once expanded. A
#: "billion laughs" document (aliases of aliases of aliases) is refused above it.
MAX_ALIAS_EXPANSION = 100_000


def read_text_file(path: str | Path, what: str = "file") -> str:
    """The UTF-8 text of ``path``, which must be a regular file.

    A pipe, a device (``/dev/zero``, ``/dev/stdin``), a socket or a folder is refused
    before anything is read: reading a FIFO waits for a writer for ever, and a device
    like ``/dev/zero`` never ends. The file is opened without blocking, so a FIFO is
    refused at once, whether or not something writes to it.

    Raises
    ------
    ConfigError
        Naming ``what`` and the path: not found, not a regular file, unreadable, not
        UTF-8.
    """
    import os
    import stat

    p = Path(path)
    try:
        fd = os.open(p, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except FileNotFoundError:
        raise ConfigError(f"{what.capitalize()} not found: {p}") from None
    except PermissionError as exc:
        raise ConfigError(
            f"Cannot read {what} {p}: {exc.strerror}. This user may not read it (ls -l "
            "shows who may): make it readable, or give a copy this user can read."
        ) from None
    except OSError as exc:
        raise ConfigError(f"Cannot read {what} {p}: {exc.strerror}.") from None
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            kind = (
                "a folder"
                if stat.S_ISDIR(mode)
                else "a pipe (FIFO)"
                if stat.S_ISFIFO(mode)
                else "a socket"
                if stat.S_ISSOCK(mode)
                else "a device"
            )
            raise ConfigError(
                f"{what.capitalize()} {p} is {kind}, not a regular file; write it to a file "
                "and give that file's path."
            )
        chunks = []
        while chunk := os.read(fd, 1 << 20):
            chunks.append(chunk)
    except OSError as exc:
        raise ConfigError(f"Cannot read {what} {p}: {exc.strerror}.") from None
    finally:
        os.close(fd)
    data = b"".join(chunks)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(
            f"Cannot read {what} {p}: it is not UTF-8 text (byte {exc.start + 1}: "
            f"{exc.reason}). Is it the right file?"
        ) from None


def load_yaml(path: str | Path, what: str = "config file") -> tuple[Any, dict[tuple, int]]:
    """Parse a YAML file safely; return the data and the 1-based line of each key path.
    ``what`` names the file in errors ("query file", "taxonomy").

    Raises :class:`ConfigError` naming the file and line for malformed YAML, for a
    missing or unreadable file, and for a document whose aliases expand beyond
    :data:`MAX_ALIAS_EXPANSION` nodes (or refer to themselves).
    """
    p = Path(path)
    text = read_text_file(p, what)
    data, node = _parse_yaml(text, str(p))
    lines: dict[tuple, int] = {}
    _walk(node, (), lines, set())
    return data, lines


def load_yaml_text(text: str, source: str = "<text>") -> Any:
    """Parse YAML text safely, with the alias bound of :func:`load_yaml`.

    Examples
    --------
    >>> load_yaml_text("a: [1, 2]")
    {'a': [1, 2]}
    """
    return _parse_yaml(text, source)[0]


class _UniqueKeyLoader(yaml.SafeLoader):
    """PyYAML's safe loader, refusing a mapping that gives one key twice.

    PyYAML keeps the last value of a repeated key without a word, so a config that sets
    ``threshold:`` twice, or a query file with two ``present:`` sections, would lose one
    silently. The keys compared are the constructed ones (``1`` and ``1.0`` are the same
    key, as they would be in the loaded dict). Keys merged in with ``<<: *anchor`` may be
    overridden, as YAML intends; only the keys written in the mapping itself are checked.
    """

    source = "<text>"

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen: dict[Any, Any] = {}
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue
                key = self.construct_object(key_node, deep=True)
                try:
                    first = seen.get(key)
                except TypeError:  # an unhashable key: PyYAML refuses it below
                    continue
                if first is not None:
                    raise ConfigError(
                        f"{self.source}:{key_node.start_mark.line + 1}: duplicate key "
                        f"{key!r} (first given on line {first.start_mark.line + 1}); YAML "
                        "keeps only the last one. Give each key once."
                    )
                seen[key] = key_node
        return super().construct_mapping(node, deep=deep)


def _parse_yaml(text: str, source: str) -> tuple[Any, Any]:
    loader = _UniqueKeyLoader(text)
    loader.source = source
    try:
        node = loader.get_single_node()
        if node is None:
            return None, None
        _check_expansion(node, source)
        return loader.construct_document(node), node
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None) or getattr(exc, "context_mark", None)
        problem = getattr(exc, "problem", None) or str(exc)
        loc = f"{source}:{mark.line + 1}:{mark.column + 1}" if mark else source
        raise ConfigError(
            f"{loc}: malformed YAML: {problem}. Check indentation and quoting."
        ) from None
    except RecursionError:
        raise ConfigError(f"{source}: the YAML is nested too deeply to be a config.") from None
    finally:
        loader.dispose()


def _check_expansion(root: Any, source: str) -> None:
    """Refuse a document whose aliases expand too far, or into themselves."""
    size: dict[int, int] = {}
    distinct = 0
    on_path: set[int] = set()
    stack: list[tuple[Any, bool]] = [(root, False)]
    while stack:
        node, done = stack.pop()
        key = id(node)
        children = _children(node)
        if done:
            on_path.discard(key)
            size[key] = 1 + sum(size[id(c)] for c in children)
            if size[key] > distinct + MAX_ALIAS_EXPANSION:
                raise ConfigError(
                    f"{source}: the YAML's aliases (*name) expand to more than "
                    f"{MAX_ALIAS_EXPANSION:,} extra nodes; refusing to load it (a YAML "
                    "'billion laughs' document). Write the values out, or use fewer aliases."
                )
            continue
        if key in size:
            continue
        if key in on_path:
            raise ConfigError(
                f"{source}: a YAML alias refers to the node that contains it (a recursive "
                "alias); refusing to load it."
            )
        distinct += 1
        on_path.add(key)
        stack.append((node, True))
        for child in children:
            if id(child) in on_path:
                raise ConfigError(
                    f"{source}: a YAML alias refers to the node that contains it (a "
                    "recursive alias); refusing to load it."
                )
            if id(child) not in size:
                stack.append((child, False))


def _children(node: Any) -> list[Any]:
    if isinstance(node, yaml.MappingNode):
        return [n for pair in node.value for n in pair]
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    return []


def _walk(node, prefix: tuple, lines: dict[tuple, int], seen: set[int]) -> None:
    # Each node is visited once: an alias does not repeat the walk of its anchor.
    if node is None or id(node) in seen:
        return
    seen.add(id(node))
    if isinstance(node, yaml.MappingNode):
        for k, v in node.value:
            key = k.value
            lines[(*prefix, key)] = k.start_mark.line + 1
            _walk(v, (*prefix, key), lines, seen)
    elif isinstance(node, yaml.SequenceNode):
        for i, v in enumerate(node.value):
            lines[(*prefix, i)] = v.start_mark.line + 1
            _walk(v, (*prefix, i), lines, seen)
