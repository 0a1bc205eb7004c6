"""The method configs shipped with the package, by name: ``-c demo:quash-taxonomy``.

They are the YAML files of ``quash_plugins/data/configs/``; ``<group>-<name>.yaml`` is
named ``<group>:<name>`` (``demo-quash-taxonomy.yaml`` is ``demo:quash-taxonomy``).
Only files that are method configs count (the demo's taxonomy file lives there too).

Each file starts with comments: the first sentence describes it, and a line
``# needs: ...`` says what it needs besides the package (downloaded weights, a server).
A config without that line runs offline with what the package ships (``demo:*`` use the
shipped MiniLM encoder).

Examples
--------
>>> find_shipped("demo:vlmaps").path.name
'demo-vlmaps.yaml'
>>> find_shipped("demo:vlmaps").needs is None
True
"""

from __future__ import annotations

import dataclasses
import json
import re
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from .errors import ConfigError, closest, near_paths

#: A ``key: value`` entry of a config line (block or flow style) with a plain value.
_ENTRY_RE = re.compile(r"\b([a-z_]+):[ \t]+([^\s,{}\[\]#'\"]+)")

#: A shipped config's name: ``group:name``.
NAME_RE = re.compile(r"^[a-z0-9][a-z0-9_]*:[a-z0-9][a-z0-9_.-]*$")


@dataclass(frozen=True)
class ShippedConfig:
    """One shipped method config."""

    name: str
    path: Path
    description: str
    needs: str | None
    encoder: str

    @property
    def offline(self) -> bool:
        """True when it runs with what the package ships (no downloads, no server)."""
        return self.needs is None

    def portable_text(self) -> str:
        """The config's text with each option that names a file (``file:``,
        ``taxonomy:``, ...: :func:`~.config.names_a_file`) beside it made absolute, so
        that a copy saved anywhere (``quash configs NAME > mine.yaml``) still finds the
        shipped taxonomy; everything else, comments included, as shipped."""
        from .config import names_a_file

        folder = self.path.parent

        def absolute(m: re.Match) -> str:
            key, name = m.group(1), m.group(2)
            target = folder / name
            if not names_a_file(key, name) or Path(name).is_absolute() or not target.is_file():
                return m.group(0)
            # a JSON string is a YAML string
            return m.group(0)[: m.start(2) - m.start(0)] + json.dumps(str(target))

        return _ENTRY_RE.sub(absolute, self.path.read_text(encoding="utf-8"))

    def data(self) -> dict:
        """The config as a dict (parsed safely, as every config file is)."""
        from .yaml_files import load_yaml_text

        return dict(load_yaml_text(self.path.read_text(encoding="utf-8"), str(self.path)))


#: The shipped peers' rules given the query alone (``demo:<name>``): VLMaps' rule over
#: [query, "other"], ConceptFusion's relative threshold, LERF's relevancy.
QUERY_PEERS = ("vlmaps", "conceptfusion", "lerf")
#: The shipped peers' rules given the label list, the fair peers of a comparison in which
#: QuASH sees the label list: VLMaps' argmax over its categories, OpenScene's label argmax.
LIST_PEERS = ("vlmaps-labels", "openscene-labels")


def config_dir() -> Path:
    """The folder of the shipped configs (package data)."""
    return Path(str(resources.files("quash_plugins.data").joinpath("configs")))


def _comments(text: str) -> tuple[str, str | None]:
    """(first sentence of the leading comment block, the ``needs:`` line or None)."""
    lines, needs = [], None
    for line in text.splitlines():
        if not line.startswith("#"):
            break
        body = line.lstrip("#").strip()
        if body.lower().startswith("needs:"):
            needs = body.split(":", 1)[1].strip() or None
        else:
            lines.append(body)
    prose = " ".join(x for x in lines if x)
    m = re.search(r"(?<=[.!?])\s", prose)
    return (prose[: m.start()] if m else prose), needs


def _is_method_config(data: object) -> bool:
    from .config import QuashConfig

    if not isinstance(data, dict) or "encoder" not in data:
        return False
    fields = {f.name for f in dataclasses.fields(QuashConfig)}
    return set(data) <= fields


def shipped_configs() -> list[ShippedConfig]:
    """Every shipped method config, sorted by name."""
    from .yaml_files import load_yaml_text

    out = []
    for path in sorted(config_dir().glob("*.yaml")):
        group, _, rest = path.stem.partition("-")
        if not rest:
            continue
        text = path.read_text(encoding="utf-8")
        data = load_yaml_text(text, str(path))
        if not _is_method_config(data):
            continue
        description, needs = _comments(text)
        enc = data["encoder"]
        encoder = str(enc.get("name") if isinstance(enc, dict) else enc)
        if isinstance(enc, dict) and enc.get("preset"):
            encoder += f" ({enc['preset']})"
        out.append(ShippedConfig(f"{group}:{rest}", path, description, needs, encoder))
    return sorted(out, key=lambda c: c.name)


def find_shipped(name: str) -> ShippedConfig:
    """The shipped config called ``name``; a :class:`ConfigError` naming the close ones."""
    configs = {c.name: c for c in shipped_configs()}
    if name in configs:
        return configs[name]
    group, sep, rest = name.partition(":")
    same = {c.partition(":")[2]: c for c in configs if sep and c.startswith(f"{group}:")}
    if same:  # within the group: 'demo:' alone made 'demo:nope' look like 'demo:lerf'
        near = closest(rest, same)
        guess = same[near] if near else None
    else:
        guess = closest(name, configs)
    hint = f" Did you mean {guess}?" if guess else ""
    raise ConfigError(
        f"No shipped config is named {name!r}.{hint} Shipped: {', '.join(configs)} "
        "('quash configs' describes them)."
    )


def resolve_config_path(ref: str | Path) -> Path:
    """The YAML file of a config reference: an existing file, else a shipped name.

    Raises :class:`ConfigError` when ``ref`` is neither; the message names the shipped
    configs so a first ``-c quash.yaml`` finds the ones that exist.
    """
    path = Path(ref).expanduser()
    if path.exists():
        return path
    text = str(ref)
    if NAME_RE.match(text):
        return find_shipped(text).path
    shipped = [c.name for c in shipped_configs()]
    near = near_paths(path, suffixes=(".yaml", ".yml")) + _near_shipped(path, shipped)
    if near:
        hint = f" Did you mean {' or '.join(near)}?"
    else:
        hint = (
            " A shipped config can be given by name instead (-c demo:quash-taxonomy); "
            f"shipped: {', '.join(shipped)}."
        )
    raise ConfigError(f"Config file not found: {text}.{hint}")


def _near_shipped(path: Path, shipped: list[str]) -> list[str]:
    """Shipped names whose part after the colon is ``path``'s stem, or whose file name it
    is (``demo-quash-labels.yaml``, as ``quash configs`` lists the files: that config
    alone), else close to it (``quash-labels`` -> ``demo:quash-labels``,
    ``lseg:quash-labels``)."""
    import difflib

    stem = path.stem if path.suffix in (".yaml", ".yml") else path.name
    own_file = [n for n in shipped if n.replace(":", "-", 1) == stem]
    if own_file:
        return own_file
    exact = [n for n in shipped if n.split(":", 1)[-1] == stem]
    if exact or path.suffix in (".yaml", ".yml"):
        return exact  # a file name: only an exact stem, not every 'quash-*' config
    parts = sorted({n.split(":", 1)[-1] for n in shipped})
    close = set(difflib.get_close_matches(stem, parts, n=2, cutoff=0.8))
    return [n for n in shipped if n.split(":", 1)[-1] in close]
