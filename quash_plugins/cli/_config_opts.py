"""Config options shared by the subcommands: ``-c/--config``, ``--no-cache``, ``--device``."""

from __future__ import annotations

import argparse
import logging
from typing import Any

from ..core.config import QuashConfig
from ..core.errors import ConfigError, UsageError
from ..core.shipped import LIST_PEERS, resolve_config_path

log = logging.getLogger(__name__)


def add_config_option(parser: argparse.ArgumentParser, multiple: bool = False) -> None:
    if multiple:
        parser.add_argument(
            "-c",
            "--config",
            action="append",
            metavar="CONFIG",
            dest="configs",
            default=None,
            help="Method config: a YAML file or a shipped config's name (e.g. "
            "demo:quash-labels; 'quash configs' lists them). Repeat to compare methods. "
            "Default: the fair comparison, the default config beside the peers given the "
            f"same label list ({', '.join(FAIR_PEERS)}, with the default config's encoder).",
        )
    else:
        parser.add_argument(
            "-c",
            "--config",
            metavar="CONFIG",
            default=None,
            action=_OneConfig,
            help="Method config: a YAML file or a shipped config's name (e.g. "
            "demo:quash-labels; 'quash configs' lists them). Default: "
            f"{_default_summary()}: the map's label list (its label names, or "
            "MAP.taxonomy.yaml beside it), else the shipped vocabulary, with refinement and "
            "the presence check (core.config.DEFAULT_CONFIG; docs/config.md).",
        )


class _OneConfig(argparse.Action):
    """``-c`` of a command that runs one config: given twice is an error, not the last
    one silently (``quash eval`` compares several)."""

    def __call__(self, parser, namespace, values, option_string=None):
        first = getattr(namespace, self.dest, None)
        if first is not None:
            parser.error(
                f"{option_string} is given twice ({first}, {values}); this command runs one "
                "config. To compare methods, run quash eval MAP -c A -c B."
            )
        setattr(namespace, self.dest, values)


def add_runtime_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--no-cache",
        action="store_true",
        help="Do not read or write the text-embedding cache (the llm heuristic's cached "
        "query sets are still used: 'quash cache clear --llm' deletes them).",
    )
    parser.add_argument(
        "--device",
        default=None,
        help="Override the config's device, a plugin section's own device: included "
        "(auto, cpu, cuda, cuda:N, mps). One that is not on this machine is refused "
        "before the map is read.",
    )


#: The peers a command comparing methods runs beside the default config when given no
#: ``-c``: VLMaps' rule over its category list and OpenScene's label argmax, each given the
#: same label list as the default config.
FAIR_PEERS = tuple(f"demo:{name}" for name in LIST_PEERS)


def fair_default_configs() -> list[QuashConfig]:
    """The configs of ``quash eval`` given no ``-c``: the fair peers, then the default
    config; the peers take the default config's encoder (a map has one text encoder).

    The VLMaps peer's ``templates: vlmaps-or-default`` takes VLMaps' prompt templates
    when VLMaps is installed, else ours, said at INFO (the user did not choose the peer).
    """
    import dataclasses

    default = QuashConfig.default()
    peers = [load_config(name) for name in FAIR_PEERS]
    return [dataclasses.replace(p, encoder=default.encoder) for p in peers] + [default]


def _default_summary() -> str:
    """The default config in a few words, read from core.config (one source)."""
    cfg = QuashConfig.default()
    return f"{cfg.encoder.name} + {cfg.heuristic.name} + {cfg.classifier.name}"


def load_config(ref: str | None) -> QuashConfig:
    """The config of ``-c``: a YAML file or a shipped config's name; the default if None."""
    if ref is None:
        return QuashConfig.default()
    try:
        path = resolve_config_path(ref)
    except ConfigError as exc:
        raise UsageError(str(exc)) from None
    return QuashConfig.from_yaml(path)


def apply_runtime_options(cfg: QuashConfig, args: argparse.Namespace) -> QuashConfig:
    if getattr(args, "no_cache", False):
        cfg.cache = False
    if getattr(args, "device", None):
        from ..core.config import check_device
        from ..core.errors import ConfigError

        try:
            cfg.device = check_device(args.device, "--device")
        except ConfigError as exc:
            raise UsageError(str(exc)) from None
        _override_plugin_devices(cfg, cfg.device)
    check_devices_present(cfg, flag=bool(getattr(args, "device", None)))
    return cfg


def check_devices_present(cfg: QuashConfig, flag: bool = False) -> None:
    """Refuse, before any map is read, a device that is not on this machine: ``cuda``
    without a CUDA GPU, ``cuda:N`` beyond the GPUs torch sees, ``mps`` without Apple's
    MPS where the encoder would run on it (the classification pass runs on the CPU for
    ``mps``). ``flag``: the devices came from ``--device``, which the error names;
    else the error names the config file, the line and the field (``device:`` or a
    section's own, ``encoder.device:``). ``auto`` and ``cpu`` import nothing."""
    from ..core.config import PluginSpec
    from ..engine.device import device_unavailable

    asked: list[tuple[str, tuple[str, ...]]] = []
    # mps reaches only an encoder that takes a device and has none of its own
    if not _is_mps(cfg.device) or (
        "device" not in cfg.encoder.params and _encoder_takes_device(cfg)
    ):
        asked.append((cfg.device, ("device",)))
    for section, value in vars(cfg).items():
        if isinstance(value, PluginSpec):
            device = value.params.get("device")
            if isinstance(device, str) and (section == "encoder" or not _is_mps(device)):
                asked.append((device, (section, "device")))
    for device, keys in asked:
        try:
            why = device_unavailable(device)
        except ConfigError:
            continue  # not a device at all: the plugin or the config says so, as before
        if why is None:
            continue
        if flag:
            raise UsageError(
                f"--device {device}: {why}; use --device auto (a GPU when there is one, "
                "else the CPU) or --device cpu."
            )
        field = ".".join(keys)
        where = cfg.location(*keys)
        raise ConfigError(
            f"{where}{field}: {device!r}: {why}; set {field}: auto (a GPU when there is one, "
            "else the CPU) or cpu"
            + (f" in {cfg.source}" if cfg.source else "")
            + ", or pass --device cpu."
        )


def _is_mps(device: str) -> bool:
    return str(device).strip().lower() == "mps"


def _encoder_takes_device(cfg: QuashConfig) -> bool:
    """Whether the config's encoder takes a ``device`` (the built-in torch encoders do);
    False when it cannot be loaded (building it says why)."""
    from ..core import registry
    from ..core.errors import QuashError

    try:
        obj = registry.load("encoders", cfg.encoder.name)
    except QuashError:
        return False
    accepted = registry.accepted_params(obj)
    return accepted is None or "device" in accepted


def _override_plugin_devices(cfg: QuashConfig, device: str) -> None:
    """``--device`` overrides the config's device, a plugin section's own ``device:``
    (``encoder: {name: open-clip, device: cuda}``) included: the command line wins over
    the file, as every other flag does. Each section overridden is said at info level."""
    from ..core.config import PluginSpec

    def walk(params: dict, where: str) -> None:
        for k, v in params.items():
            if k == "device" and isinstance(v, str) and v != device:
                log.info(
                    "--device %s overrides %s.device: %s (%s)",
                    device,
                    where,
                    v,
                    cfg.source or cfg.name,
                )
                params[k] = device
            elif isinstance(v, dict) and "name" in v:  # a nested plugin (combine, base)
                walk(v.get("params") if isinstance(v.get("params"), dict) else v, f"{where}.{k}")

    for section, value in vars(cfg).items():
        if isinstance(value, PluginSpec):
            walk(value.params, section)


def input_files(map_path: str | None, configs: list[QuashConfig]) -> list[str]:
    """The files a run reads besides the map, that no output may replace: the map's
    sidecar taxonomy (``MAP.taxonomy.yaml``, read by the taxonomy heuristics), each
    config's YAML file and every file it names (:meth:`QuashConfig.named_files`:
    ``encoder.file``, a label list's ``unlisted`` names, a prompt-template file...). A
    file that does not exist is listed too: nothing will then be read from it, and checks
    skip it."""
    from ..heuristics import taxonomy_path_beside

    found: list[str] = []
    if map_path:
        beside = taxonomy_path_beside(map_path)
        if beside is not None:
            found.append(str(beside))
    for cfg in configs:
        if cfg.source:
            found.append(str(cfg.source))
        found += cfg.named_files()
    return [f for f in found if "://" not in f and not f.startswith("hf-hub:")]


def check_map_inputs(lmap: Any, outputs: list[tuple[str, Any]]) -> None:
    """Refuse, once the map is read and before any query runs, an output that is one of
    the files read with it (``lmap.source["inputs"]``: VLMaps' ``obj2cls_dict.txt``,
    OpenScene's scene points, a feature folder's images...), which :func:`input_files`
    cannot know before the map is read. ``outputs`` holds ``(option, path)`` pairs;
    ``--force`` never lets an output replace one."""
    from ..core.atomic import check_not_input
    from ..core.types import source_inputs

    inputs = source_inputs(getattr(lmap, "source", None))
    for what, path in outputs:
        if path:
            check_not_input(path, inputs, what=what)


def add_adapter_options(parser: argparse.ArgumentParser) -> None:
    """``-o/--option KEY=VALUE``: an option of the adapter that reads the map."""
    parser.add_argument(
        "--option",
        "-o",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="Adapter option, e.g. -o cs=0.05 -o positions=upstream (values parsed as YAML; "
        "over the config's adapter section); repeatable.",
    )


def adapter_options(args: argparse.Namespace) -> dict:
    """The ``-o KEY=VALUE`` options as a mapping (values parsed as YAML)."""
    return key_values(getattr(args, "option", None) or [], "--option")


def key_values(items: list[str], option: str) -> dict:
    """``KEY=VALUE`` command-line items as a mapping, values parsed as YAML."""
    from ..core.yaml_files import load_yaml_text

    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise UsageError(f"{option} expects KEY=VALUE; got {item!r}.")
        out[key.strip()] = load_yaml_text(value, f"{option} {key.strip()}") if value else ""
    return out
