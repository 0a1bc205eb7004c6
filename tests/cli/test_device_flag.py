"""``--device`` is a command-line override: it wins over the config's top-level device
and over a plugin section's own ``device:``, as every other flag wins over the file."""

from __future__ import annotations

import argparse
import logging

import pytest

from quash_plugins.cli._config_opts import apply_runtime_options
from quash_plugins.core.config import QuashConfig
from quash_plugins.engine.pipeline import Quash


def _config() -> QuashConfig:
    return QuashConfig.from_dict(
        {
            "device": "cuda",
            "encoder": {"name": "minilm", "device": "cuda"},
            "heuristic": {
                "name": "combine",
                "synonyms": {"name": "none"},
                "antonyms": {"name": "label-list"},
            },
            "classifier": {"name": "svm-rbf", "device": "cuda:1"},
        }
    )


def test_device_flag_overrides_a_plugin_sections_own_device(caplog):
    with caplog.at_level(logging.INFO, logger="quash_plugins.cli._config_opts"):
        cfg = apply_runtime_options(_config(), argparse.Namespace(device="cpu"))
    assert cfg.device == "cpu"
    assert cfg.encoder.params["device"] == "cpu"
    assert cfg.classifier.params["device"] == "cpu"
    said = caplog.text
    assert "encoder.device: cuda" in said and "classifier.device: cuda:1" in said
    quash = Quash.from_config(cfg)
    assert quash.encoder.device == "cpu"  # the section said cuda; the flag said cpu


def test_without_the_flag_a_sections_device_is_kept(monkeypatch):
    # on a machine with two GPUs: the sections' cuda and cuda:1 are there
    # (tests/cli/test_cli_device.py: refused where they are not)
    torch = pytest.importorskip("torch")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 2)
    cfg = apply_runtime_options(_config(), argparse.Namespace(device=None))
    assert cfg.device == "cuda" and cfg.encoder.params["device"] == "cuda"
    assert cfg.classifier.params["device"] == "cuda:1"
