"""The Hugging Face libraries' log lines (the hub's retries while a model loads) go
through ``quash``'s logging: ``--quiet`` silences their warnings, the default and
``--verbose`` show them as ``WARNING  ...`` lines, and a library's own handler prints
nothing beside them."""

from __future__ import annotations

import logging
import sys

import pytest

from quash_plugins.cli._output import setup_logging
from quash_plugins.encoders._runtime import LIBRARY_LOGGERS, require, route_library_logs

RETRY = "Retrying in 1s [Retry 1/5]."


@pytest.fixture(autouse=True)
def _library_loggers_restored():
    saved = {}
    for name in LIBRARY_LOGGERS:
        lg = logging.getLogger(name)
        saved[name] = (lg.handlers[:], lg.level, lg.propagate)
    yield
    for name, (handlers, level, propagate) in saved.items():
        lg = logging.getLogger(name)
        lg.handlers[:], lg.propagate = handlers, propagate
        lg.setLevel(level)


def _hub_as_imported() -> None:
    """What huggingface_hub does on import: a stderr handler of its own, at WARNING."""
    hub = logging.getLogger("huggingface_hub")
    hub.handlers[:] = [logging.StreamHandler(sys.stderr)]
    hub.setLevel(logging.WARNING)
    hub.propagate = True


def _retry_then_error() -> None:
    log = logging.getLogger("huggingface_hub.utils._http")
    log.warning(RETRY)
    log.error("the request failed")


@pytest.mark.parametrize(
    ("verbose", "quiet", "shown"),
    [
        (0, True, ["ERROR    huggingface_hub: the request failed"]),
        (
            0,
            False,
            [f"WARNING  huggingface_hub: {RETRY}", "ERROR    huggingface_hub: the request failed"],
        ),
        (
            1,
            False,
            [f"WARNING  huggingface_hub: {RETRY}", "ERROR    huggingface_hub: the request failed"],
        ),
    ],
)
def test_hub_lines_follow_quiet_and_verbose(verbose, quiet, shown, capsys):
    _hub_as_imported()
    setup_logging(verbose, quiet)
    require("json", "none")  # an encoder's import: the libraries are routed after it
    _retry_then_error()
    err = capsys.readouterr().err.splitlines()
    assert [line for line in err if line.strip()] == shown


def test_a_program_that_logs_itself_is_left_alone(capsys, monkeypatch):
    package = logging.getLogger("quash_plugins")  # as a program leaves it, whatever ran before
    monkeypatch.setattr(package, "handlers", [])
    monkeypatch.setattr(package, "propagate", True)
    _hub_as_imported()
    before = logging.getLogger("huggingface_hub").handlers[:]
    route_library_logs()  # the package's logging was not set up by the command
    assert logging.getLogger("huggingface_hub").handlers == before
    _retry_then_error()
    assert RETRY in capsys.readouterr().err


def test_quiet_expand_prints_no_hub_warning(monkeypatch, tmp_path, capsys):
    """Through the command: a hub warning while the encoder loads its model."""
    pytest.importorskip("sentence_transformers")
    from quash_plugins.cli.main import main
    from quash_plugins.encoders import _sentence_transformers as st_mod

    real = st_mod._quiet_loading

    def loading_with_a_retry():
        logging.getLogger("huggingface_hub.utils._http").warning(RETRY)
        return real()

    monkeypatch.setattr(st_mod, "_quiet_loading", loading_with_a_retry)
    monkeypatch.setattr(st_mod, "_LOADED", {})  # the model is loaded in the command
    (tmp_path / "tax.yaml").write_text("chair: [armchair]\nsofa: [couch]\n", encoding="utf-8")
    cfg = tmp_path / "q.yaml"
    cfg.write_text("encoder: minilm\nheuristic: {name: taxonomy, file: tax.yaml}\n")
    _hub_as_imported()
    argv = ["expand", "a comfy seat", "-c", str(cfg), "--no-cache", "--device", "cpu"]
    assert main(["-q", *argv]) == 0
    assert RETRY not in capsys.readouterr().err
    monkeypatch.setattr(st_mod, "_LOADED", {})
    _hub_as_imported()
    assert main(argv) == 0
    err = capsys.readouterr().err
    assert f"WARNING  huggingface_hub: {RETRY}" in err and err.count(RETRY) == 1
