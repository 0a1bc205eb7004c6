from __future__ import annotations

import contextlib

import pytest

from quash_plugins import Encoder
from quash_plugins.core import registry
from quash_plugins.core.errors import ConfigError, PluginError


def test_builtins_are_listed_from_metadata():
    assert {"npz"} <= set(registry.available("adapters"))
    assert {"svm-rbf", "contrast"} <= set(registry.available("classifiers"))
    assert {"none", "static"} <= set(registry.available("heuristics"))
    assert "table" in registry.available("encoders")
    infos = {i.name: i for i in registry.plugins("classifiers")}
    assert infos["svm-rbf"].dist == "quash-plugins"


def test_singular_kind_is_accepted_and_unknown_kind_rejected():
    assert registry.available("classifier") == registry.available("classifiers")
    with pytest.raises(PluginError, match="Unknown plugin kind 'widgets'"):
        registry.available("widgets")


def test_unknown_name_lists_known_and_closest():
    with pytest.raises(PluginError) as err:
        registry.create("classifiers", "svm-rfb")
    msg = str(err.value)
    assert "'svm-rfb' is not registered" in msg
    assert "contrast" in msg and "Did you mean 'svm-rbf'" in msg


def test_unknown_parameter_is_rejected_with_accepted_list():
    with pytest.raises(ConfigError) as err:
        registry.create("classifiers", "svm-rbf", gama=1.0)
    assert "'gama'" in str(err.value) and "gamma" in str(err.value)


def test_create_passes_params():
    clf = registry.create("classifiers", "svm-rbf", C=3.0)
    assert clf.C == 3.0


class _Enc(Encoder):
    name = "mine"
    dim = 2

    def encode_text(self, texts):  # pragma: no cover - not called
        raise AssertionError


def test_register_duplicate_and_qualified_names():
    registry.register("encoders", "dup", _Enc, dist="pkg-a")
    registry.register("encoders", "dup", _Enc, dist="pkg-b")
    try:
        with pytest.raises(PluginError, match="several distributions: pkg-a, pkg-b"):
            registry.load("encoders", "dup")
        assert registry.load("encoders", "pkg-a:dup") is _Enc
        with pytest.raises(PluginError, match="already registered"):
            registry.register("encoders", "dup", _Enc, dist="pkg-a")
        with pytest.raises(PluginError, match="not provided by distribution 'pkg-c'"):
            registry.load("encoders", "pkg-c:dup")
    finally:
        registry.unregister("encoders", "dup", dist="pkg-a")
        registry.unregister("encoders", "dup", dist="pkg-b")
    assert "dup" not in registry.available("encoders")


def test_register_rejects_interface_breakers():
    class NotAnEncoder:
        pass

    with pytest.raises(PluginError, match="lacks encode_text, dim, fingerprint"):
        registry.register("encoders", "bad", NotAnEncoder)


def test_loading_is_cached():
    a = registry.load("classifiers", "contrast")
    b = registry.load("classifiers", "contrast")
    assert a is b


def test_register_rejects_a_subclass_that_leaves_a_method_abstract():
    from quash_plugins import Encoder

    class HalfEncoder(Encoder):
        dim = 4

    with pytest.raises(PluginError, match="does not implement encode_text"):
        registry.register("encoders", "half", HalfEncoder)
    assert "half" not in registry.available("encoders")


class _DuckEncoder:
    """Has dim and encode_text but does not subclass Encoder: no fingerprint()."""

    dim = 4

    def encode_text(self, texts):  # pragma: no cover - never built
        raise AssertionError


def test_an_encoder_that_does_not_subclass_encoder_is_refused_when_it_loads():
    """The text cache and the map's provenance call fingerprint(): a duck-typed class
    used to be listed as ok and then fail every query with an AttributeError."""
    with pytest.raises(PluginError) as err:
        registry.register("encoders", "duck", _DuckEncoder, dist="pkg-duck")
    msg = str(err.value)
    assert "'duck' from distribution 'pkg-duck'" in msg
    assert "lacks fingerprint" in msg and "Subclass quash_plugins.Encoder" in msg
    assert "duck" not in registry.available("encoders")


def test_a_factory_whose_instance_breaks_the_interface_is_refused_when_built():
    registry.register("encoders", "duck-factory", lambda: _DuckEncoder(), dist="pkg-duck")
    try:
        with pytest.raises(PluginError, match="'duck-factory'.*lacks fingerprint"):
            registry.create("encoders", "duck-factory")
    finally:
        registry.unregister("encoders", "duck-factory", dist="pkg-duck")


class _NeedsWeights(_Enc):
    """Opens its weights file when built, as a lab's own model would."""

    def __init__(self, weights: str = "/nonexistent/lab-weights.pt") -> None:
        open(weights, "rb")  # noqa: SIM115 - raises before anything is kept


def test_a_plugin_that_raises_when_built_is_named_with_its_distribution():
    """Before: the plugin's FileNotFoundError reached the command line as an
    'unexpected error' naming neither the plugin nor its distribution."""
    registry.register("encoders", "needs-weights", _NeedsWeights, dist="pkg-lab")
    try:
        with pytest.raises(PluginError) as err:
            registry.create("encoders", "needs-weights", weights="/nonexistent/w.pt")
    finally:
        registry.unregister("encoders", "needs-weights", dist="pkg-lab")
    msg = str(err.value)
    assert msg.startswith(
        "Encoder 'needs-weights' from distribution 'pkg-lab' failed to build with weights: "
        "FileNotFoundError:"
    )
    assert "/nonexistent/w.pt" in msg and "fix or uninstall 'pkg-lab'" in msg
    assert isinstance(err.value.__cause__, FileNotFoundError)


def test_the_split_keeps_the_public_import_paths_and_one_discovery_cache():
    """Discovery (core._entry_points) and distributions (core._distributions) moved out
    of registry.py: their public names are still imported from the registry, as the
    same objects, and registry.refresh() still empties the one cache scan() fills."""
    from quash_plugins.core import _distributions, _entry_points
    from quash_plugins.core.registry import (  # the paths plugins and the CLI use
        BUILTIN_DIST,
        GROUP_PREFIX,
        KINDS,
        MisplacedEntryPoint,
        PluginInfo,
        distribution_is_editable,
        distribution_of,
        is_editable,
        misplaced_entry_points,
        note_distribution,
    )

    assert PluginInfo is _entry_points.PluginInfo
    assert MisplacedEntryPoint is _entry_points.MisplacedEntryPoint
    assert misplaced_entry_points is _entry_points.misplaced_entry_points
    assert (KINDS, BUILTIN_DIST, GROUP_PREFIX) == (
        ("encoders", "heuristics", "classifiers", "adapters"),
        "quash-plugins",
        "quash_plugins.",
    )
    assert distribution_of is _distributions.distribution_of
    assert is_editable is _distributions.is_editable
    assert distribution_is_editable is _distributions.distribution_is_editable
    assert note_distribution is _distributions.note_distribution
    registry.available("classifiers")
    assert "classifiers" in _entry_points._scanned
    registry.refresh()
    assert "classifiers" not in _entry_points._scanned
    assert "svm-rbf" in registry.available("classifiers")  # scanned again


@contextlib.contextmanager
def _entry_point(kind: str, name: str, target: str, load, dist: str = "pkg-imports"):
    """An entry point ``name`` of ``dist`` naming ``target``, whose import runs ``load``,
    registered for the block."""
    from quash_plugins.core import _entry_points
    from quash_plugins.core._entry_points import PluginInfo

    registry.available(kind)  # scanned
    info = PluginInfo(kind, name, target, dist, "0.1", _loader=load)
    _entry_points._scanned[kind].append(info)
    try:
        yield info
    finally:
        _entry_points._scanned[kind].remove(info)


def _broken(kind: str, name: str):
    """A plugin of ``broken-dist`` whose import fails for a missing module."""

    def load():
        raise ImportError("No module named 'missing_driver'")

    return _entry_point(kind, name, f"broken_{name}:Thing", load, dist="broken-dist")


def _load_error(name: str, target: str, load) -> str:
    """The error of loading encoder ``name`` whose entry point names ``target`` and whose
    import runs ``load``."""
    with _entry_point("encoders", name, target, load), pytest.raises(PluginError) as err:
        registry.load("encoders", name)
    return str(err.value)


def test_a_plugin_the_config_names_fails_with_an_error_not_a_skipped_warning(caplog):
    """Before, a configured plugin that failed to import logged 'WARNING ... It is
    skipped.' and then raised the same text as an error: it was not skipped."""
    from quash_plugins.core import once
    from quash_plugins.core.errors import PluginError

    once.forget("registry")
    with _broken("encoders", "brokenenc"):
        with caplog.at_level("WARNING"), pytest.raises(PluginError, match="failed to import"):
            registry.create("encoders", "brokenenc")
        assert "skipped" not in caplog.text


def test_a_broken_adapter_that_auto_detection_passes_over_is_warned_about_once(caplog):
    from quash_plugins.core import once
    from quash_plugins.core.maps import _ordered_adapters

    once.forget("registry")
    with _broken("adapters", "brokenadapter"):
        with caplog.at_level("WARNING"):
            names = [n for n, _ in _ordered_adapters()]
            _ordered_adapters()
        assert "brokenadapter" not in names and "npz" in names
        warned = [r.getMessage() for r in caplog.records if "brokenadapter" in r.getMessage()]
        assert len(warned) == 1 and warned[0].endswith("It is skipped."), warned
        assert "broken-dist" in warned[0]


def test_unknown_parameter_suggests_a_typo_fix_not_another_word():
    """'check_finite' (a ConceptFusion option) given to image-features was answered
    "Did you mean 'cache_frames'?" (difflib ratio 0.5); a real typo still gets its fix."""
    from quash_plugins.core.errors import ConfigError

    with pytest.raises(ConfigError) as info:
        registry.create("adapters", "image-features", check_finite=True)
    assert "check_finite" in str(info.value) and "cache_frames" in str(info.value)
    assert "Did you mean" not in str(info.value)
    with pytest.raises(ConfigError, match="Did you mean 'cache_frames'"):
        registry.create("adapters", "image-features", cache_frame=4)


def _from_numpy_import_a_typo():
    from numpy import no_such_name_in_numpy  # noqa: F401


def _import_a_submodule_numpy_lacks():
    import importlib

    importlib.import_module("numpy.no_such_submodule")


@pytest.mark.parametrize(
    ("target", "load", "wrong"),
    [
        # the plugin's module exists; a name it imports from an installed package does not
        ("numpy.my_encoder:Thing", _from_numpy_import_a_typo, "it names does not exist"),
        ("my_plugin.encoder:Thing", _import_a_submodule_numpy_lacks, "not installed"),
    ],
)
def test_an_import_error_of_an_installed_package_is_not_called_not_installed(target, load, wrong):
    """A plugin module doing ``from numpy import typo`` was reported as an entry point
    naming a module that does not exist, and ``import mypackage.no_such_file`` (its own
    package's missing helper module) as 'needs the Python module 'mypackage', which is
    not installed': neither is the fix. The import error's own text is reported."""
    msg = _load_error("imports-badly", target, load)
    assert wrong not in msg
    assert "no_such_" in msg and "Fix or uninstall 'pkg-imports'" in msg


class _ImportsATypoWhenBuilt(_Enc):
    def __init__(self) -> None:
        _import_a_submodule_numpy_lacks()


class _ImportsATypoWhenEncoding(_Enc):
    def encode_text(self, texts):
        _from_numpy_import_a_typo()


def test_an_import_error_when_built_or_encoding_is_not_called_not_installed(tmp_path):
    """The same mistake in ``__init__`` or ``encode_text`` said 'numpy ... is not
    installed'; a dependency that is really missing still says so."""
    from quash_plugins.core.errors import EncoderError, missing_module
    from quash_plugins.core.text import encode_texts

    registry.register("encoders", "typo-built", _ImportsATypoWhenBuilt, dist="pkg-imports")
    try:
        with pytest.raises(PluginError) as err:
            registry.create("encoders", "typo-built")
    finally:
        registry.unregister("encoders", "typo-built", dist="pkg-imports")
    assert "not installed" not in str(err.value)
    assert "numpy.no_such_submodule" in str(err.value)
    with pytest.raises(EncoderError) as err:
        encode_texts(_ImportsATypoWhenEncoding(), ["chair"])
    assert "not installed" not in str(err.value)
    assert "no_such_name_in_numpy" in str(err.value)
    with pytest.raises(ImportError) as err:
        import a_dependency_that_is_not_installed  # noqa: F401
    assert missing_module(err.value) == "a_dependency_that_is_not_installed"


def test_an_entry_point_with_a_dot_for_the_colon_is_given_the_line_to_write():
    """``bow = "my_pkg.BagOfWordsEncoder"`` was told only that the module it names does
    not exist; the class is there, behind a dot where the colon belongs."""
    import importlib

    msg = _load_error(
        "dotted-target",
        "quash_plugins.Encoder",
        lambda: importlib.import_module("quash_plugins.Encoder"),
    )
    assert "The module 'quash_plugins.Encoder' it names does not exist" in msg
    assert (
        'a colon separates the module from the object: dotted-target = "quash_plugins:Encoder"'
        in msg
    )


def test_a_missing_part_of_a_namespace_package_is_the_module_to_install(tmp_path, monkeypatch):
    """``import google.generativeai`` with only another google-* distribution installed:
    the module to install is google.generativeai, not the namespace 'google' (which is
    there)."""
    import importlib

    from quash_plugins.core.errors import missing_module

    (tmp_path / "nsquash_ns" / "present").mkdir(parents=True)
    (tmp_path / "nsquash_ns" / "present" / "__init__.py").write_text("")
    monkeypatch.syspath_prepend(str(tmp_path))

    def error(module):
        with pytest.raises(ImportError) as err:
            importlib.import_module(module)
        return err.value

    assert missing_module(error("nsquash_ns.absent")) == "nsquash_ns.absent"
    assert missing_module(error("nsquash_ns.absent.deeper")) == "nsquash_ns.absent"
    assert missing_module(error("nsquash_ns.present.no_such_module")) is None


def test_a_built_in_whose_library_lacks_what_it_imports_is_a_plugin_error(monkeypatch):
    """A library of another version (``from numpy import a_name_it_has_not``) when a
    built-in is built was said to be not installed (before e0a926f); it is a PluginError
    saying an installed package lacks what it imports, not an 'unexpected error'."""
    info = next(i for i in registry.plugins("encoders") if i.name == "table")
    monkeypatch.setattr(info, "_obj", _ImportsATypoWhenBuilt)
    with pytest.raises(PluginError) as err:
        registry.create("encoders", "table")
    msg = str(err.value)
    assert msg.startswith("Encoder 'table' cannot be built: ModuleNotFoundError: No module")
    assert "numpy.no_such_submodule" in msg and "not installed" not in msg
    assert "install the versions quash-plugins requires" in msg


def test_a_syntax_error_in_a_plugin_names_the_whole_path_of_its_file(tmp_path, monkeypatch):
    """Python's message names the file by its base name ('helpers.py, line 2'), which a
    plugin of several packages has more than one of."""
    import importlib

    (tmp_path / "synquash_pkg" / "sub").mkdir(parents=True)
    (tmp_path / "synquash_pkg" / "__init__.py").write_text("from .sub import helpers\n")
    (tmp_path / "synquash_pkg" / "sub" / "__init__.py").write_text("")
    (tmp_path / "synquash_pkg" / "sub" / "helpers.py").write_text("x = 1\ndef f(:\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    msg = _load_error(
        "syntax-error", "synquash_pkg:Thing", lambda: importlib.import_module("synquash_pkg")
    )
    assert f"Fix line 2 of {tmp_path / 'synquash_pkg' / 'sub' / 'helpers.py'}." in msg
