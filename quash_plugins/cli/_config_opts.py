"""Config options shared by the subcommands: ``-c/--config``, ``--no-cache``, ``--device``."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..core.config import QuashConfig
from ..core.errors import UsageError


def add_config_option(parser: argparse.ArgumentParser, multiple: bool = False) -> None:
    if multiple:
        parser.add_argument(
            "-c",
            "--config",
            action="append",
            metavar="CONFIG",
            dest="configs",
            default=None,
            help="Method config (YAML); repeat to compare methods side by side.",
        )
    else:
        parser.add_argument(
            "-c",
            "--config",
            metavar="CONFIG",
            default=None,
            help="Method config (YAML). Default: the label list of the map (its label names, "
            "or MAP.taxonomy.yaml beside it), else the shipped vocabulary, with refinement and "
            "the presence check (core.config.DEFAULT_CONFIG; docs/config.md).",
        )


def add_runtime_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--no-cache", action="store_true", help="Do not read or write the text-embedding cache."
    )
    parser.add_argument(
        "--device",
        default=None,
        help="Override the config's device (auto, cpu, cuda, cuda:N, mps).",
    )


def load_config(path: str | None) -> QuashConfig:
    if path is None:
        return QuashConfig.default()
    if not Path(path).exists():
        raise UsageError(f"Config file not found: {path}")
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
    return cfg
