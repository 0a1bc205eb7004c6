"""``quash_plugins.testing.check_plugin``: one plugin's checks, named as the user names it.

Two distributions register the same name here (as after ``pip install`` of a plugin
that shadows another): ``dist:name`` checks that distribution's plugin only, and a
failure names the plugin and the check. A plugin the kit cannot build says what to add.
"""

from __future__ import annotations

import sys

import numpy as np
import pytest

from quash_plugins import Encoder
from quash_plugins.core import registry
from quash_plugins.core.errors import ConfigError
from quash_plugins.testing import check_plugin, parametrize_with_checks


class _Good(Encoder):
    name = "kit-twin"

    @property
    def dim(self):
        return 4

    def encode_text(self, texts):
        rows = np.zeros((len(texts), 4), np.float32)
        for i, t in enumerate(texts):
            rows[i, len(t) % 4] = 1.0
        return rows


class _Float64(_Good):
    def encode_text(self, texts):
        return super().encode_text(texts).astype(np.float64)


class _NeedsFile(_Good):
    name = "kit-needs-file"

    def __init__(self, file: str):
        self.file = file


@pytest.fixture
def twins():
    registry.register("encoders", "kit-twin", _Good, dist="kit-good")
    registry.register("encoders", "kit-twin", _Float64, dist="kit-bad")
    registry.register("encoders", "kit-needs-file", _NeedsFile, dist="kit-good")
    yield
    registry.unregister("encoders", "kit-twin", dist="kit-good")
    registry.unregister("encoders", "kit-twin", dist="kit-bad")
    registry.unregister("encoders", "kit-needs-file", dist="kit-good")


def test_a_qualified_name_checks_that_distribution_only(twins, tmp_path):
    check_plugin("encoders", "kit-good:kit-twin", tmp_path / "good")  # passes: float32
    with pytest.raises(AssertionError) as err:
        check_plugin("encoders", "kit-bad:kit-twin", tmp_path / "bad")
    message = str(err.value)
    # the plugin and the check it failed, then what is wrong
    assert message.startswith("encoders:kit-bad:kit-twin-check_encoder_output: ")
    assert "float64" in message


def test_an_unknown_name_is_an_error_not_a_pass(twins, tmp_path):
    with pytest.raises(ConfigError, match="No encoder plugin named 'kit-none'"):
        check_plugin("encoders", "kit-none", tmp_path)
    with pytest.raises(ConfigError, match="'kit-other:kit-twin'"):
        check_plugin("encoders", "kit-other:kit-twin", tmp_path)


def test_a_plugin_the_kit_cannot_build_says_what_to_add(twins, tmp_path):
    with pytest.raises(ConfigError) as err:
        check_plugin("encoders", "kit-needs-file", tmp_path)
    message = str(err.value)
    # the plugin, its distribution, the parameter, and where to write it
    assert "'kit-needs-file' from distribution 'kit-good' needs parameter 'file'" in message
    assert "encoder: {name: kit-needs-file, file: ...}" in message
    assert "conformance_params(tmp_path)" in message and "conformance_skip" in message
    # with conformance_params the kit builds it, and the checks run
    _NeedsFile.conformance_params = classmethod(lambda cls, tmp: {"file": str(tmp / "f")})
    try:
        check_plugin("encoders", "kit-needs-file", tmp_path)
    finally:
        del _NeedsFile.conformance_params


def test_a_mistake_in_conformance_params_is_named_as_one(twins, tmp_path):
    """A typo in what conformance_params returns was reported as the plugin refusing a
    parameter, which the author had written nowhere but there; a conformance_params
    without @classmethod ended in a bare TypeError about a missing 'tmp_path'."""

    def kit_error(conformance_params) -> str:
        _NeedsFile.conformance_params = conformance_params
        try:
            with pytest.raises(ConfigError) as err:
                check_plugin("encoders", "kit-needs-file", tmp_path)
        finally:
            del _NeedsFile.conformance_params
        return str(err.value)

    message = kit_error(classmethod(lambda cls, tmp: {"fil": str(tmp / "f")}))
    assert "does not accept parameter 'fil'" in message and "Did you mean 'file'" in message
    assert "_NeedsFile.conformance_params(tmp_path) returns (fil): fix that" in message

    def plain(self, tmp_path):  # the @classmethod forgotten
        return {"file": str(tmp_path / "f")}

    message = kit_error(plain)
    assert "_NeedsFile.conformance_params (encoder 'kit-needs-file') is a plain method" in message
    assert "decorate it with @classmethod" in message


@pytest.fixture
def misplaced(tmp_path, monkeypatch):
    """An installed distribution (its metadata) whose encoder sits in a group quash-plugins
    does not read: ``quash_plugins.encoder``, singular."""
    info = tmp_path / "lab_encoders-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: lab-encoders\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text(
        "[quash_plugins.encoder]\nlab-encoder = lab_encoders:LabEncoder\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    registry.refresh()
    yield
    registry.refresh()


def test_an_entry_point_in_a_misspelt_group_is_named_with_the_group_to_use(misplaced, tmp_path):
    # Before, the kit said the plugin was not installed (or asked whether the
    # distribution was), though it is: its entry point is in the wrong group.
    with pytest.raises(ConfigError) as err:
        check_plugin("encoders", "lab-encoder", tmp_path)
    message = str(err.value)
    assert "'quash_plugins.encoder'" in message and "'lab-encoders'" in message
    assert "move it to 'quash_plugins.encoders'" in message

    with pytest.raises(LookupError) as err:
        parametrize_with_checks(dist="lab-encoders")
    message = str(err.value)
    assert "move it to 'quash_plugins.encoders'" in message
    assert "Is the distribution installed" not in message
    # a selection that matches no misplaced entry point keeps the plain answer
    with pytest.raises(LookupError, match="Is the distribution installed"):
        parametrize_with_checks(dist="no-such-dist")


def test_a_misspelt_name_or_distribution_is_given_the_registered_one(tmp_path):
    # Before: "Is the distribution installed (pip install -e .)?" for a distribution
    # that is installed, and "is installed" for a name one letter off a built-in.
    with pytest.raises(LookupError) as err:
        parametrize_with_checks(kinds="encoders", dist="quash-plugns")
    assert "Did you mean dist 'quash-plugins'?" in str(err.value), err.value
    with pytest.raises(LookupError) as err:
        parametrize_with_checks(names=["minilmm"])
    assert "Did you mean 'minilm' for 'minilmm'?" in str(err.value), err.value
    with pytest.raises(ConfigError) as err:
        check_plugin("classifiers", "svm-rbff", tmp_path)
    assert "Did you mean 'svm-rbf' for 'svm-rbff'?" in str(err.value), err.value


def test_a_config_that_omits_a_required_parameter_is_told_whose_and_where(twins):
    # Before: Python's "__init__() missing 1 required positional argument: 'file'",
    # naming neither the distribution nor where the value goes.
    from quash_plugins import Quash

    config = {"encoder": "kit-needs-file", "heuristic": "none", "classifier": "contrast"}
    with pytest.raises(ConfigError) as err:
        Quash.from_config({**config, "cache": False})
    message = str(err.value)
    assert message.startswith("encoder: Encoder 'kit-needs-file' from distribution 'kit-good'")
    assert "needs parameter 'file', which was not given" in message
    assert "encoder: {name: kit-needs-file, file: ...}" in message
    assert "--encoder-option file=..." in message
    assert "__init__()" not in message
    # given, it builds
    built = Quash.from_config({**config, "encoder": {"name": "kit-needs-file", "file": "f"}})
    assert built.encoder.file == "f"


class _RefusesDim(_Good):
    name = "kit-refuses-dim"

    def __init__(self, dim: int = 4):
        if dim > 8:
            raise ValueError("dim must be at most 8 for this model")
        self.dim_ = dim


def test_a_value_the_plugin_refuses_names_its_distribution_and_what_it_was_given():
    # Before: "Encoder 'kit-refuses-dim': dim must be at most 8 ...", without the
    # distribution, though any other exception raised when built names it.
    from quash_plugins import Quash

    registry.register("encoders", "kit-refuses-dim", _RefusesDim, dist="lab-vlm")
    try:
        with pytest.raises(ConfigError) as err:
            Quash.from_config({"encoder": {"name": "kit-refuses-dim", "dim": 16}, "cache": False})
    finally:
        registry.unregister("encoders", "kit-refuses-dim", dist="lab-vlm")
    message = str(err.value)
    assert (
        "Encoder 'kit-refuses-dim' from distribution 'lab-vlm' failed to build with dim" in message
    )
    assert "ValueError: dim must be at most 8 for this model" in message
    assert "fix or uninstall 'lab-vlm'" in message


class _NeedsOneText(_Good):
    name = "kit-needs-one-text"

    def encode_text(self, texts):
        texts[0]  # a model batch API that needs one text at least
        return super().encode_text(texts)


class _Crashes(_Good):
    name = "kit-crashes"

    def encode_text(self, texts):
        raise RuntimeError("CUDA error: device-side assert triggered")


def test_a_check_the_plugin_raises_in_names_the_plugin_and_the_check(tmp_path):
    # Before: the plugin's bare IndexError / RuntimeError, naming neither the plugin nor
    # the check, though a failure is documented to start with both.
    from quash_plugins.testing import check_encoder

    registry.register("encoders", "kit-needs-one-text", _NeedsOneText, dist="lab-vlm")
    registry.register("encoders", "kit-crashes", _Crashes, dist="lab-vlm")
    try:
        with pytest.raises(AssertionError) as err:
            check_plugin("encoders", "kit-needs-one-text", tmp_path / "a")
        message = str(err.value)
        assert message.startswith("encoders:kit-needs-one-text-check_encoder_empty: ")
        assert "encode_text([]) raised IndexError" in message
        assert "np.zeros((0, self.dim), np.float32)" in message
        assert isinstance(err.value.__cause__.__cause__, IndexError)  # kept for the traceback

        with pytest.raises(AssertionError) as err:
            check_plugin("encoders", "kit-crashes", tmp_path / "b")
        message = str(err.value)
        assert message.startswith("encoders:kit-crashes-check_encoder_output: ")
        assert "the plugin raised RuntimeError: CUDA error: device-side assert" in message

        with pytest.raises(AssertionError) as err:
            check_encoder(_Crashes(), tmp_path / "c")
        assert str(err.value).startswith("encoder 'kit-crashes': check_encoder_output: ")
        assert isinstance(err.value.__cause__, RuntimeError)
    finally:
        registry.unregister("encoders", "kit-needs-one-text", dist="lab-vlm")
        registry.unregister("encoders", "kit-crashes", dist="lab-vlm")


def test_a_plugin_registered_as_another_kind_is_named_with_the_group_to_use(tmp_path, monkeypatch):
    # An Encoder whose entry point its author put in quash_plugins.heuristics. Before:
    # quash plugins said "it lacks expand. Subclass quash_plugins.Heuristic" (not the
    # fix), and the kit that the encoder was not installed.
    (tmp_path / "lab_vlm.py").write_text(
        "from quash_plugins.testing import HashingEncoder\n\n\n"
        "class LabEncoder(HashingEncoder):\n    name = 'lab-vlm'\n"
    )
    info = tmp_path / "lab_vlm-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: lab-vlm\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text(
        "[quash_plugins.heuristics]\nlab-vlm = lab_vlm:LabEncoder\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    registry.refresh()
    try:
        with pytest.raises(registry.PluginError) as err:
            registry.load("heuristics", "lab-vlm")
        message = str(err.value)
        assert "It is an encoder (quash_plugins.Encoder)" in message
        assert (
            "move the entry point 'lab-vlm' from group 'quash_plugins.heuristics' to "
            "'quash_plugins.encoders' in the pyproject.toml of 'lab-vlm'"
        ) in message
        assert "Subclass quash_plugins.Heuristic" not in message

        with pytest.raises(ConfigError) as err:
            check_plugin("encoders", "lab-vlm", tmp_path / "kit")
        message = str(err.value)
        assert "registers 'lab-vlm' (lab_vlm:LabEncoder) as a heuristic" in message
        assert "move it to 'quash_plugins.encoders'" in message
        with pytest.raises(
            LookupError, match="as a heuristic, in group 'quash_plugins.heuristics'"
        ):
            parametrize_with_checks("encoders", dist="lab-vlm")
    finally:
        registry.refresh()
        sys.modules.pop("lab_vlm", None)


def test_registering_a_plugin_as_another_kind_says_which_kind_it_is():
    from quash_plugins.testing import HashingEncoder

    with pytest.raises(registry.PluginError, match="It is an encoder .*register it as 'encoders'"):
        registry.register("heuristics", "lab-vlm", HashingEncoder, dist="lab-vlm")
