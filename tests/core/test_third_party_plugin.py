"""A real third-party distribution, pip-installed, is discovered like a built-in."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import traceback
from pathlib import Path

import numpy as np
import pytest
from _pip import pip_install

from quash_plugins import Quash
from quash_plugins.core import registry
from quash_plugins.core.errors import EncoderError, PluginError

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """pip-install the example plugin and the broken plugin into a private target dir."""
    target = tmp_path_factory.mktemp("site")
    pip_install(EXAMPLES / "quash-char-ngram", target)
    pip_install(EXAMPLES / "quash-broken-plugin", target)
    sys.path.insert(0, str(target))
    registry.refresh()
    yield target
    sys.path.remove(str(target))
    for name in [m for m in sys.modules if m.startswith(("quash_char_ngram", "quash_broken"))]:
        del sys.modules[name]
    registry.refresh()


def test_discovered_and_listed_with_distribution(installed):
    assert "char-ngram" in registry.available("encoders")
    info = registry.info("encoders", "char-ngram")
    assert info.dist == "quash-char-ngram" and info.version == "0.2.0"


def test_fingerprint_names_the_plugin_distribution_and_version(installed, monkeypatch):
    """Upgrading a plugin package must not serve text embeddings cached by the version
    before: the fingerprint (the text cache's key) hashes the distribution's version."""
    enc = registry.create("encoders", "char-ngram")
    top = type(enc).__module__.partition(".")[0]
    assert registry.distribution_of(type(enc).__module__) == "quash-char-ngram==0.2.0"
    before = enc.fingerprint()
    monkeypatch.setitem(registry._DISTRIBUTIONS, top, "quash-char-ngram==0.3.0")
    assert enc.fingerprint() != before
    monkeypatch.setitem(registry._DISTRIBUTIONS, top, "quash-char-ngram==0.2.0")
    assert enc.fingerprint() == before


def test_usable_by_name_from_a_config(installed, tmp_path):
    rng = np.random.default_rng(0)
    from quash_char_ngram import CharNgramEncoder

    enc = CharNgramEncoder(dim=64)
    T = enc.encode_text(["chair", "table"])
    E = np.concatenate(
        [T[0] + 0.05 * rng.normal(size=(20, 64)), T[1] + 0.05 * rng.normal(size=(20, 64))]
    ).astype(np.float32)
    np.savez(tmp_path / "m.npz", embeddings=E)
    cfg = tmp_path / "c.yaml"
    cfg.write_text(
        "encoder: {name: char-ngram, dim: 64}\nclassifier: contrast\nnegatives: [table, other]\n"
    )
    r = Quash.from_config(cfg).query(tmp_path / "m.npz", "chair")
    assert r.mask[:20].all() and not r.mask[20:].any()


def test_passes_the_conformance_kit(installed, tmp_path):
    from test_testing_encoder_checks import ENCODER_CHECK_NAMES

    from quash_plugins.testing import plugin_checks

    checks = plugin_checks(dist="quash-char-ngram")
    assert {c.name for c in checks} == {"char-ngram"}  # its one encoder, every check
    # the pinned names, not the kit's own list: a check dropped from the kit fails here
    assert [c.check.__name__ for c in checks] == ENCODER_CHECK_NAMES
    for c in checks:
        c(tmp_path / c.check.__name__)


def test_the_example_package_runs_the_kit_in_its_own_test_suite(installed, tmp_path):
    """The example's tests/test_conformance.py, the one line docs/plugins.md asks of a
    plugin package, collects every check of the example's encoder, and each passes."""
    tests = EXAMPLES / "quash-char-ngram" / "tests"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(installed), *sys.path])}
    done = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-p", "no:dash"]
        + ["--rootdir", str(tests), "-c", os.devnull, "--basetemp", str(tmp_path / "t")]
        + [str(tests)],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-2000:]
    from quash_plugins.testing import plugin_checks

    n = len(plugin_checks(dist="quash-char-ngram"))
    assert n >= 8 and f"{n} passed" in done.stdout, done.stdout[-1000:]


def test_broken_plugin_is_reported_and_others_keep_working(installed):
    with pytest.raises(PluginError) as err:
        registry.load("encoders", "broken-encoder")
    msg = str(err.value)
    assert "quash-broken-plugin" in msg and "a_dependency_that_is_not_installed" in msg
    with pytest.raises(PluginError, match="breaks the classifier interface"):
        registry.load("classifiers", "not-a-classifier")
    # everything else still loads
    assert registry.create("encoders", "char-ngram").dim == 256
    assert registry.create("classifiers", "contrast") is not None


def test_cli_lists_plugin_and_broken_status(installed):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(installed), *sys.path])}
    out = subprocess.run(
        [sys.executable, "-m", "quash_plugins.cli.main", "plugins", "--json"],
        capture_output=True,
        text=True,
        env=env,
        check=True,
    )
    rows = {(r["kind"], r["name"]): r for r in json.loads(out.stdout)}
    assert rows[("encoders", "char-ngram")]["distribution"] == "quash-char-ngram"
    assert rows[("encoders", "char-ngram")]["status"] == "ok"
    broken = rows[("encoders", "broken-encoder")]
    assert broken["status"] == "error" and "quash-broken-plugin" in broken["error"]
    assert rows[("classifiers", "svm-rbf")]["status"] == "ok"


def test_entry_point_typos_name_the_entry_point_and_the_fix(installed):
    with pytest.raises(PluginError) as err:
        registry.load("encoders", "typo-module")
    msg = str(err.value)
    assert "The module 'quash_broken_plugn' it names does not exist" in msg
    assert "entry point 'typo-module' in group 'quash_plugins.encoders'" in msg
    assert "'quash-broken-plugin' (its pyproject.toml)" in msg
    with pytest.raises(PluginError) as err:
        registry.load("classifiers", "typo-object")
    msg = str(err.value)
    assert "Module 'quash_broken_plugin' has no 'NotAClasifier'" in msg
    assert "Did you mean quash_broken_plugin:NotAClassifier?" in msg


def test_subclass_missing_an_abstract_method_is_reported_when_loaded(installed):
    with pytest.raises(PluginError) as err:
        registry.load("encoders", "half-encoder")
    msg = str(err.value)
    assert "breaks the encoder interface: it does not implement encode_text" in msg
    assert registry.info("encoders", "half-encoder").status == "error"


def test_missing_library_when_built_or_used_names_the_module(installed, tmp_path):
    with pytest.raises(PluginError) as err:
        registry.create("encoders", "needs-a-library")
    msg = str(err.value)
    assert "from distribution 'quash-broken-plugin' cannot be built" in msg
    assert "needs the Python module 'a_dependency_that_is_not_installed'" in msg
    np.savez(tmp_path / "m.npz", embeddings=np.eye(8, dtype=np.float32))
    q = Quash.from_config(
        {"encoder": "lazy-library", "heuristic": "none", "classifier": "contrast", "cache": False}
    )
    with pytest.raises(EncoderError, match="'lazy-library' .*needs the Python module 'a_depend"):
        q.query(tmp_path / "m.npz", "chair")


def test_cli_table_shows_errors_in_full_and_qualified_names(installed):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(installed), *sys.path])}
    env["COLUMNS"] = "80"
    out = subprocess.run(
        [sys.executable, "-m", "quash_plugins.cli.main", "plugins", "--kind", "encoders"],
        capture_output=True,
        text=True,
        env=env,
        check=True,
    ).stdout
    flat = " ".join(out.split())
    # every name whole (no ellipsis), and every error's fix readable below the table
    assert "…" not in out and "sentence-transformers" in out
    assert "The module 'quash_broken_plugn' it names does not exist" in flat
    assert "it does not implement encode_text" in flat


def test_debug_shows_the_plugins_own_import_traceback(installed, tmp_path):
    """A plugin author debugging an import error sees their own module's frames: in
    ``quash plugins --debug`` and in a query's traceback (the cause is kept)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(installed), *sys.path])}
    cmd = [sys.executable, "-m", "quash_plugins.cli.main", "plugins", "--kind", "encoders"]
    plain = subprocess.run(cmd, capture_output=True, text=True, env=env, check=True)
    assert "Traceback" not in plain.stdout and "quash plugins --debug" in plain.stdout
    # the errors are printed once, below the table, not also as log warnings
    assert "failed to import" not in plain.stderr
    debug = subprocess.run([*cmd, "--debug"], capture_output=True, text=True, env=env)
    assert debug.returncode == 0
    assert "Traceback (most recent call last)" in debug.stderr
    assert "Traceback" not in debug.stdout  # the table stays clean
    # whole lines, as Python prints them: the plugin's own file and line on one line
    assert re.search(r'File ".*quash_broken_plugin[/\\]__init__\.py", line \d+', debug.stderr)

    np.savez(tmp_path / "m.npz", embeddings=np.eye(8, dtype=np.float32))
    cfg = tmp_path / "broken.yaml"
    cfg.write_text("encoder: broken-encoder\nheuristic: none\nclassifier: contrast\n")
    from quash_plugins.cli.main import main

    with pytest.raises(PluginError, match=r"broken.yaml:1: encoder: .*failed to import") as err:
        main(["query", str(tmp_path / "m.npz"), "chair", "-c", str(cfg), "--debug"])
    cause = err.value.__cause__
    assert isinstance(cause, ImportError)
    frames = "".join(traceback.format_tb(cause.__traceback__))
    assert re.search(r"quash_broken_plugin[/\\]__init__\.py", frames), frames


def test_the_kit_gives_a_plugin_that_does_not_load_one_failing_check(installed, tmp_path):
    """Not one failure of the same import error per check: one check, with the fix."""
    from quash_plugins.testing import plugin_checks

    checks = plugin_checks(dist="quash-broken-plugin")
    by_name: dict[str, list[str]] = {}
    for c in checks:
        by_name.setdefault(c.name, []).append(c.check.__name__)
    for broken in ("broken-encoder", "typo-module", "half-encoder", "not-a-classifier"):
        assert by_name[broken] == ["check_plugin_loads"], (broken, by_name[broken])
    assert len(by_name["lazy-library"]) > 1  # it loads; it fails when used
    single = next(c for c in checks if c.name == "typo-module")
    with pytest.raises(PluginError, match="does not exist.*Fix or uninstall"):
        single(tmp_path)


def test_an_entry_point_naming_an_instance_names_the_class_to_write(installed):
    # Before: only "points at quash_broken_plugin:AN_INSTANCE, which is not a class or
    # factory", with neither the entry point to edit nor what to write in it.
    with pytest.raises(PluginError) as err:
        registry.load("encoders", "an-instance")
    msg = str(err.value)
    assert "It names an instance of LazyLibrary" in msg
    assert "entry point 'an-instance' in group 'quash_plugins.encoders'" in msg
    assert "'quash-broken-plugin' (its pyproject.toml)" in msg
    assert 'an-instance = "quash_broken_plugin:LazyLibrary"' in msg


def test_an_entry_point_naming_a_module_names_its_plugin_class(tmp_path):
    # a module with one Encoder subclass: the fix names it
    import types

    from quash_plugins import Encoder
    from quash_plugins.core.registry import PluginInfo

    module = types.ModuleType("lab_vlm")

    class LabEncoder(Encoder):
        dim = 4

        def encode_text(self, texts):  # pragma: no cover - never called
            return np.zeros((len(texts), 4), np.float32)

    LabEncoder.__module__ = "lab_vlm"
    module.LabEncoder = LabEncoder
    module.Encoder = Encoder  # imported, not defined there: not a candidate
    info = PluginInfo("encoders", "lab", "lab_vlm", "lab-vlm", "1.0", _loader=lambda: module)
    with pytest.raises(PluginError) as err:
        registry._load_info(info)
    msg = str(err.value)
    assert "It names the module 'lab_vlm'" in msg
    assert 'lab = "lab_vlm:LabEncoder"' in msg and "'lab-vlm' (its pyproject.toml)" in msg


def _dim_method_encoder():
    """An encoder whose author wrote ``def dim(self)`` and forgot ``@property``."""
    from quash_plugins import Encoder

    class DimMethod(Encoder):
        name = "dim-method"

        def dim(self):
            return 4

        def encode_text(self, texts):  # pragma: no cover - never reached
            return np.zeros((len(texts), 4), np.float32)

    return DimMethod


def test_dim_written_as_a_method_is_named_with_the_fix():
    # Before: the class loaded ('ok' in quash plugins) and a query or make-scene ended in
    # "unexpected error: TypeError: int() argument must be ... not 'method'".
    from quash_plugins.core.errors import ConfigError

    cls = _dim_method_encoder()
    try:
        with pytest.raises(PluginError) as err:
            registry.register("encoders", "dim-method", cls, dist="lab-vlm")
    finally:
        registry.unregister("encoders", "dim-method", dist="lab-vlm")
    msg = str(err.value)
    assert "'dim-method' from distribution 'lab-vlm'" in msg
    assert "defines dim as a method of" in msg and "@property" in msg

    # a factory's instance is checked when it is built
    registry.register("encoders", "dim-method-factory", lambda: cls(), dist="lab-vlm")
    try:
        with pytest.raises(PluginError, match="defines dim as a method.*@property"):
            registry.create("encoders", "dim-method-factory")
        with pytest.raises((PluginError, ConfigError), match="@property"):
            Quash.from_config({"encoder": "dim-method-factory", "cache": False})
    finally:
        registry.unregister("encoders", "dim-method-factory", dist="lab-vlm")
