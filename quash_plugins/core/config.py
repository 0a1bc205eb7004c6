"""Pipeline configuration: a dataclass checked strictly, loaded from YAML or a dict.

The same fields feed the YAML files, the docs' config reference
(:func:`config_reference`) and :class:`quash_plugins.Quash`. An unknown key is an
error naming the key, the file and the line; a plugin parameter is either honoured
by the plugin or rejected when the plugin is built.

Examples
--------
>>> cfg = QuashConfig.from_dict({"encoder": {"name": "minilm"}, "classifier": "contrast"})
>>> cfg.classifier.name
'contrast'
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .errors import ConfigError, closest
from .types import DEFAULT_NEGATIVES
from .yaml_files import load_yaml

_PATH_KEYS = (
    "file",
    "path",
    "checkpoint",
    "vocabulary",
    "taxonomy",
    "cache_dir",
    "labels_file",
    "points",  # the openscene adapter's point cloud
    "images",  # the image-features adapter's folder of RGB frames
    "label_names",  # the openscene and vlmaps adapters' file of names (a list is no path)
)


@dataclass
class PluginSpec:
    """A plugin name plus its keyword parameters (``{name: svm-rbf, C: 1.0}``)."""

    name: str
    params: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, **self.params}


#: The heuristic of a config that names none: works with every encoder.
DEFAULT_HEURISTIC = PluginSpec("none")
#: The classifier of a config that names none, chosen by the quality benchmark
#: (docs/benchmarks.md); the paper's SVM is ``svm-rbf``.
DEFAULT_CLASSIFIER = PluginSpec("nearest-sample", {"k": 2})

#: The settings of refinement and of the presence check in the chosen method
#: (``demo:quash-labels``) and the default config, chosen by the quality benchmark on seeds
#: that its reported tables do not use (docs/benchmarks.md).
CHOSEN_REFINE: dict[str, Any] = {
    "classifier": "svm-rbf",
    "n_positives": 100,
    "n_negatives": 1000,
    "seeds": "top",
}
#: ``{}``: the presence check's own defaults (``engine.presence.PresenceOptions``).
CHOSEN_PRESENCE: dict[str, Any] = {}

#: The config a command runs when given no ``-c`` (``quash query MAP QUERY``), and
#: :meth:`QuashConfig.default`: safe on any map. With a label list (the map's label
#: names, or a taxonomy beside the map) it answers as the chosen method,
#: ``demo:quash-labels``; without one as ``demo:quash-vocabulary`` (the shipped
#: vocabulary stands in for the list: the ``auto`` heuristic, and ``auto`` refinement
#: seeds and growth check), so each case is the config the quality tables measure.
#: The presence check returns an empty mask for an object that is not in the map. It
#: needs a text encoder that can embed the vocabulary (any sentence or CLIP encoder).
DEFAULT_CONFIG: dict[str, Any] = {
    "name": "default",
    "encoder": "minilm",
    "heuristic": {"name": "auto"},
    "classifier": DEFAULT_CLASSIFIER.to_dict(),
    # auto: demo:quash-labels' settings (seeds: top, grow_margin: 0.0, keep_like: 0.6) for
    # a query set from a label list, demo:quash-vocabulary's (matched, null, null) for one
    # from the vocabulary
    "refine": {**CHOSEN_REFINE, "seeds": "auto"},
    "presence": {**CHOSEN_PRESENCE, "grow_margin": "auto", "keep_like": "auto"},
}


#: Devices a config may name: ``cuda:N`` picks one GPU. Anything else (``tpu``, ``xla``,
#: a typo) is refused when the config is loaded, not silently ignored.
DEVICES = ("auto", "cpu", "cuda", "cuda:N", "mps")


def check_device(value: Any, where: str = "device") -> str:
    """``value`` as a device string when it is one of :data:`DEVICES`; else ConfigError.

    Examples
    --------
    >>> check_device("cuda:1")
    'cuda:1'
    """
    if value is None:
        return "auto"
    text = str(value).strip().lower() if isinstance(value, str) else None
    if text is not None:
        kind, _, index = text.partition(":")
        if (kind in ("auto", "cpu", "cuda", "mps") and not index) or (
            kind == "cuda" and index.isdigit()
        ):
            return text
    raise ConfigError(
        f"{where}: {value!r} is not a supported device; use one of {', '.join(DEVICES)}."
    )


def _default(spec: PluginSpec):
    return lambda: PluginSpec(spec.name, dict(spec.params))


@dataclass
class QuashConfig:
    """Everything that defines a QuASH method; one YAML file per method."""

    name: str = field(default="quash", metadata={"help": "Label used in tables and plots."})
    encoder: PluginSpec = field(
        default_factory=lambda: PluginSpec("minilm"),
        metadata={"help": "Text encoder; must match the map's embedding space."},
    )
    heuristic: PluginSpec = field(
        default_factory=_default(DEFAULT_HEURISTIC),
        metadata={
            "help": "Expands the query into positives and negatives. The default, none, "
            "works with every encoder; vocabulary and taxonomy are what make QuASH pay off."
        },
    )
    classifier: PluginSpec = field(
        default_factory=_default(DEFAULT_CLASSIFIER),
        metadata={
            "help": "Trained on the text embeddings, applied to every map item. The "
            "default was chosen by the quality benchmark (docs/benchmarks.md); the "
            "paper's SVM is svm-rbf."
        },
    )
    negatives: list[str] = field(
        default_factory=lambda: list(DEFAULT_NEGATIVES),
        metadata={"help": "Generic negatives always added to the antonyms."},
    )
    threshold: float = field(
        default=0.0,
        metadata={
            "help": "Decision threshold: items with score > threshold match. Raise it "
            "for precision, lower it for recall."
        },
    )
    prompt_templates: dict[str, Any] | None = field(
        default=None,
        metadata={
            "help": "Prompt engineering for any heuristic: {mode: mean|all, templates: "
            "default|vlmaps|vlmaps-or-default|[...]|FILE, normalize: true|false "
            "(re-normalise the mean; VLMaps does not)}. null turns it off."
        },
    )
    map_negatives: dict[str, Any] | None = field(
        default=None,
        metadata={
            "help": "Map-mined negatives: vocabulary names that win many map items but "
            "are not the query ({n: 5, min_share: 0.01}). null turns it off."
        },
    )
    refine: dict[str, Any] | None = field(
        default=None,
        metadata={
            "help": "Transductive refinement: re-fit on the map's most confident matches "
            "and a sample of clear non-matches, then classify again ({classifier: svm-rbf, "
            "n_positives: 100, n_negatives: 1000, negative_quantile: 0.5, min_seed: 10, "
            "seed: 0, seeds: matched|top|auto}; auto: top for a query set from a label list, "
            "else matched; {} takes these defaults). null turns it off."
        },
    )
    presence: dict[str, Any] | None = field(
        default=None,
        metadata={
            "help": "Presence check after the last pass: keep the matched components whose "
            "grown region the query set classifies as the query; none kept means the object "
            "is absent (empty mask) ({dilate: 1, min_component: 8, margin: 0.05, "
            "keep_margin: -0.02, core_margin: 0.12, core_keep_margin: 0.03, size_margin: 0.3, "
            "flat_margin: null, support_margin: 0.12, label_name: true, k: 2, mode: filter|gate, "
            "grow: -0.25, grow_steps: null, grow_margin: 0.0 (auto: 0.0 with a label list, "
            "else null), keep_like: null (auto: 0.6 with a label list, else null), split: 2.5 "
            "(with a label list: a component that is not strong whole is also judged piece "
            "by piece, split where its items' label scores change; null: judged whole), "
            "fallback: null (e.g. 0.03, with a label list and refinement: when nothing of the "
            "refined mask passes, the first pass's mask is checked with every presence "
            "margin raised by it and answers if an object passes), reseed: true (with a "
            "label list and refinement: when nothing of the refined mask passes, refine "
            "again from what passes on the first pass's mask, and check that refit), "
            "reseed_min_component: 4 (a reseed check that finds no object is done again "
            "counting an object of this many items, by its own items only under "
            "min_component; null: no second check), "
            "grown_min_component: null (a component under it is present by its own items "
            "only, not by its grown region)}; "
            "{} takes these defaults). Needs a voxel grid, positions or frames. null turns it off."
        },
    )
    adapter: PluginSpec = field(
        default_factory=lambda: PluginSpec("auto"),
        metadata={"help": "Map adapter and its options; 'auto' sniffs the file."},
    )
    instances: dict[str, Any] | None = field(
        default_factory=dict,
        metadata={"help": "Instance grouping options ({min_size: 3, radius: ...}); null disables."},
    )
    seed: int = field(default=0, metadata={"help": "Seed for random heuristics."})
    device: str = field(
        default="auto",
        metadata={
            "help": "Where the text encoder and the classification pass run: auto (a CUDA "
            "GPU when one is visible, else the CPU), cpu, cuda, cuda:N (the map is then "
            "kept on that GPU), or mps (the encoder; the pass runs on the CPU). Anything "
            "else is refused. backend: dask classifies on the workers' CPUs."
        },
    )
    cache: bool = field(default=True, metadata={"help": "Cache text embeddings on disk."})
    chunk_mb: float = field(
        default=256.0, metadata={"help": "Working-set budget for classification, in MB."}
    )
    source: str | None = field(default=None, metadata={"help": "File the config came from."})

    # ------------------------------------------------------------------ loading
    @classmethod
    def from_dict(
        cls,
        data: dict[str, Any],
        *,
        path: str | Path | None = None,
        lines: dict[tuple, int] | None = None,
    ) -> QuashConfig:
        """Build from a plain dict, rejecting unknown keys."""
        lines = lines or {}
        where = _Where(path, lines)
        if not isinstance(data, dict):
            raise ConfigError(f"{where.at(())}the config must be a mapping of keys to values.")
        known = [f.name for f in dataclasses.fields(cls) if f.name != "source"]
        kwargs: dict[str, Any] = {}
        for key, value in data.items():
            if key not in known:
                _refuse_vlmaps_map_config(data, where.at((key,)))
                guess = closest(str(key), known)
                hint = f" Did you mean {guess!r}?" if guess else _misplaced_param(key, data)
                raise ConfigError(
                    f"{where.at((key,))}unknown key {key!r}. Known keys: {', '.join(known)}.{hint}"
                )
            kwargs[key] = _convert(cls, key, value, where, path)
        cfg = cls(**kwargs)
        cfg.source = str(path) if path else None
        cfg._where = where
        return cfg

    def location(self, *keys: Any) -> str:
        """``"FILE:LINE: "`` of the deepest of ``keys`` (``("presence", "margn")``) that
        the config file holds, ``"FILE: "`` without one, ``""`` for a config from a dict:
        the prefix of an error about that entry found after loading."""
        where = getattr(self, "_where", None)
        if where is None or where.path is None:
            return f"{self.source}: " if self.source else ""
        return where.at(tuple(keys))

    @classmethod
    def from_yaml(cls, path: str | Path) -> QuashConfig:
        """Load a YAML file, or a shipped config by name (``demo:quash-taxonomy``; see
        :mod:`quash_plugins.core.shipped`); errors name the file and the line."""
        from .shipped import resolve_config_path

        path = resolve_config_path(path)
        data, lines = load_yaml(path)
        if data is None:
            data = {}
        return cls.from_dict(data, path=path, lines=lines)

    @classmethod
    def default(cls) -> QuashConfig:
        """The config of a command given no ``-c`` (:data:`DEFAULT_CONFIG`)."""
        import copy

        return cls.from_dict(copy.deepcopy(DEFAULT_CONFIG))

    @classmethod
    def load(cls, source: str | Path | dict[str, Any] | QuashConfig) -> QuashConfig:
        if isinstance(source, QuashConfig):
            return source
        if isinstance(source, dict):
            return cls.from_dict(source)
        return cls.from_yaml(source)

    def named_files(self) -> list[str]:
        """The files this config's settings name, as read (relative paths resolved
        against its folder): every plugin parameter that :func:`names_a_file` says is one
        (``encoder.file``, a label list's ``unlisted``...; not ``cache_dir``, a folder),
        ``prompt_templates``' template file and ``map_negatives``' vocabulary. The YAML
        file itself (``source``) is not listed."""
        from .text import TEMPLATE_NAMES

        found: list[str] = []

        def walk(params: object) -> None:
            if isinstance(params, dict):
                for k, v in params.items():
                    if names_a_file(str(k), v) and k != "cache_dir":
                        found.append(v)
                    else:
                        walk(v)
            elif isinstance(params, (list, tuple)):
                for v in params:
                    walk(v)

        for value in vars(self).values():
            if isinstance(value, PluginSpec):
                walk(value.params)
        templates = (self.prompt_templates or {}).get("templates")
        if isinstance(templates, str) and templates not in TEMPLATE_NAMES:
            found.append(templates)
        vocabulary = (self.map_negatives or {}).get("vocabulary")
        if isinstance(vocabulary, str):
            found.append(vocabulary)
        return found

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for f in dataclasses.fields(self):
            if f.name == "source":
                continue
            v = getattr(self, f.name)
            out[f.name] = v.to_dict() if isinstance(v, PluginSpec) else v
        return out


class _Where:
    def __init__(self, path, lines):
        self.path = path
        self.lines = lines

    def at(self, keys: tuple) -> str:
        line = None
        for n in range(len(keys), -1, -1):
            if keys[:n] in self.lines:
                line = self.lines[keys[:n]]
                break
        if self.path is None:
            return "config: "
        return f"{self.path}:{line}: " if line else f"{self.path}: "


def _convert(cls, key: str, value: Any, where: _Where, path) -> Any:
    f = {f.name: f for f in dataclasses.fields(cls)}[key]
    if key in ("encoder", "heuristic", "classifier", "adapter"):
        return _plugin_spec(key, value, where, path)
    if key == "negatives":
        if value is None:
            return []
        if isinstance(value, str) or not isinstance(value, list):
            raise ConfigError(f"{where.at((key,))}'negatives' must be a list of strings.")
        return [str(v) for v in value]
    if key in ("prompt_templates", "map_negatives", "instances", "refine", "presence"):
        if value is None or value is False:
            return None
        if value is True:
            return {}
        if not isinstance(value, dict):
            raise ConfigError(f"{where.at((key,))}{key!r} must be a mapping, true or null.")
        if key == "prompt_templates":
            from .text import TEMPLATE_NAMES, misspelt_template_name

            value = dict(value)
            tpl = value.get("templates")
            if isinstance(tpl, str) and tpl not in TEMPLATE_NAMES:
                value["templates"] = _resolve_path(tpl, path)
                misspelt = misspelt_template_name(value["templates"])
                if misspelt:  # a name, not a file: say so here, with the file and line
                    raise ConfigError(f"{where.at((key, 'templates'))}{misspelt}")
        if key == "map_negatives" and isinstance(value.get("vocabulary"), str):
            value = {**value, "vocabulary": _resolve_path(value["vocabulary"], path)}
        return dict(value)
    typ = {
        "name": str,
        "threshold": float,
        "seed": int,
        "device": str,
        "cache": bool,
        "chunk_mb": float,
    }[key]
    if typ is bool and not isinstance(value, bool):
        raise ConfigError(f"{where.at((key,))}{key!r} must be true or false; got {value!r}.")
    try:
        out = typ(value)
    except (TypeError, ValueError):
        raise ConfigError(
            f"{where.at((key,))}{key!r} must be a {typ.__name__}; got {value!r}. ({f.metadata['help']})"
        ) from None
    if key == "chunk_mb" and not (math.isfinite(out) and out > 0):
        raise ConfigError(
            f"{where.at((key,))}'chunk_mb' must be a positive, finite number of MiB; got {value!r}."
        )
    if key == "device":
        out = check_device(value, f"{where.at((key,))}'device'")
    return out


#: Top-level keys of VLMaps' map config (``config/map_config/vlmaps.yaml``) that no
#: QuASH config has.
VLMAPS_MAP_CONFIG_KEYS = frozenset({"map_type", "pose_info", "grid_size", "cell_size"})


def _refuse_vlmaps_map_config(data: dict[str, Any], where: str) -> None:
    """VLMaps' own map config given as the QuASH config (``-c config/map_config/vlmaps.yaml``)
    says what it is; its first unknown key alone read "Did you mean 'adapter'?"."""
    found = sorted(VLMAPS_MAP_CONFIG_KEYS & {str(k) for k in data})
    if found:
        raise ConfigError(
            f"{where}this is VLMaps' map config (it has {', '.join(found)}), not a QuASH "
            "config. Give a QuASH config (encoder, heuristic, classifier...; docs/vlmaps.md, "
            "section 1). The map's grid size is read from the map, and a mobile-base map's "
            "cell_size is the option cs (quash query MAP QUERY -o cs=0.05, or adapter: "
            "{name: vlmaps, cs: 0.05} in the QuASH config)."
        )


def _misplaced_param(key: Any, data: dict[str, Any]) -> str:
    """A hint for an unknown top-level ``key`` that is a parameter of one of the config's
    plugins (``dim: 64`` beside ``encoder: bag-of-words``): where to write it; "" when
    it is none of theirs, or the plugins cannot be loaded to say."""
    from . import registry

    defaults = {f.name: f.default_factory for f in dataclasses.fields(QuashConfig)}
    for section in ("encoder", "heuristic", "classifier", "adapter"):
        spec = data.get(section) or defaults[section]().name  # type: ignore[misc]
        name = spec.get("name") if isinstance(spec, dict) else spec
        if not isinstance(name, str) or not name:
            continue
        try:
            accepted = registry.accepted_params(registry.load(f"{section}s", name))
        except Exception:  # an unknown or broken plugin: its own error comes later
            continue
        if accepted and key in accepted:
            return (
                f" {key!r} is a parameter of the {section}: write it in its section, "
                f"{section}: {{name: {name}, {key}: ...}}."
            )
    return ""


def _plugin_spec(key: str, value: Any, where: _Where, path) -> PluginSpec:
    if isinstance(value, PluginSpec):
        return value
    if isinstance(value, str):
        return PluginSpec(value)
    if not isinstance(value, dict) or "name" not in value:
        typo = [k for k in value if closest(str(k), ["name"])] if isinstance(value, dict) else []
        hint = f" Did you mean 'name' for {typo[0]!r}?" if typo else ""
        raise ConfigError(
            f"{where.at((key,))}{key!r} must be a plugin name or a mapping with 'name', "
            f"e.g. {key}: {{name: ..., <param>: <value>}}.{hint}"
        )
    params = {str(k): v for k, v in value.items() if k != "name"}
    for k, v in list(params.items()):
        if names_a_file(k, v):
            params[k] = _resolve_path(v, path)
        elif isinstance(v, dict) and "name" in v:  # nested spec (combine, templates base)
            inner = _plugin_spec(k, v, where, path)
            sub = dict(v.get("params") or {}) if isinstance(v.get("params"), dict) else None
            if sub is not None:
                inner = _plugin_spec(k, {"name": inner.name, **sub}, where, path)
                params[k] = {"name": inner.name, "params": inner.params}
            else:
                params[k] = {"name": inner.name, **inner.params}
    return PluginSpec(str(value["name"]), params)


def _template_names() -> tuple[str, ...]:
    from .text import TEMPLATE_NAMES

    return tuple(TEMPLATE_NAMES)


def names_a_file(key: str, value: Any) -> bool:
    """Whether a plugin parameter ``key: value`` names a file, read from the config
    file's folder and never replaced by an output: a ``*_file``/``*_path`` key or one of
    ``_PATH_KEYS``; ``unlisted`` unless it is ``vocabulary`` (the shipped list); the
    templates heuristic's ``templates`` unless it names a shipped list."""
    if not isinstance(value, str):
        return False
    return (
        _is_path_key(key)
        or (key == "unlisted" and value != "vocabulary")
        or (key == "templates" and value not in _template_names())
    )


def _is_path_key(k: str) -> bool:
    return k in _PATH_KEYS or k.endswith("_file") or k.endswith("_path")


def _resolve_path(value: str, config_path) -> str:
    """Resolve a relative path against the config file's directory."""
    if config_path is None or value.startswith(("hf-hub:", "http://", "https://", "~")):
        return str(Path(value).expanduser()) if value.startswith("~") else value
    p = Path(value)
    if p.is_absolute():
        return value
    return str(Path(config_path).resolve().parent / p)


def config_reference() -> str:
    """Markdown table of every config key, its default and its help (for the docs)."""
    rows = ["| key | default | meaning |", "| --- | --- | --- |"]
    for f in dataclasses.fields(QuashConfig):
        if f.name == "source":
            continue
        if f.default is not dataclasses.MISSING:
            default = f.default
        else:
            default = f.default_factory()  # type: ignore[misc]
        if isinstance(default, PluginSpec):
            default = default.to_dict()
        rows.append(f"| `{f.name}` | `{default!r}` | {f.metadata.get('help', '')} |")
    return "\n".join(rows)


if __name__ == "__main__":  # pragma: no cover - regenerates the table in docs/config.md
    print(config_reference())
