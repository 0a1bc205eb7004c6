"""The Encoder base class: what its default config() and fingerprint() record."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from quash_plugins import Encoder
from quash_plugins.core import registry
from quash_plugins.core.errors import ConfigError


class _Seeded(Encoder):
    """A plugin author's encoder that keeps its parameters and does not override config()."""

    name = "seeded"

    def __init__(self, seed: int = 0, scale: float = 1.0, device: str = "cpu") -> None:
        self.seed = seed
        self.scale = scale
        self.device = device
        self.model = object()  # not plain data: never recorded
        self._cache = {}

    @property
    def dim(self) -> int:
        return 8

    def encode_text(self, texts):
        rng = np.random.default_rng(self.seed)
        out = rng.normal(size=(len(texts), 8)) * self.scale
        return (out / np.linalg.norm(out, axis=1, keepdims=True)).astype(np.float32)


def test_default_config_records_plain_public_parameters_not_the_device():
    assert _Seeded(seed=3, scale=2.0, device="cuda").config() == {"scale": 2.0, "seed": 3}


def test_parameters_that_change_the_output_change_the_fingerprint():
    a, b = _Seeded(seed=0), _Seeded(seed=1)
    assert not np.allclose(a.encode_text(["chair"]), b.encode_text(["chair"]))
    assert a.fingerprint() != b.fingerprint()
    # the device does not change what is embedded, so cached rows are shared
    assert _Seeded(seed=0, device="cuda").fingerprint() == a.fingerprint()
    # and the fingerprint is the same in every process (no object addresses in it)
    assert a.fingerprint() == _Seeded(seed=0).fingerprint()


def test_distribution_of_an_installed_module_and_of_a_script():
    assert registry.distribution_of("quash_plugins.encoders") == (
        f"quash-plugins=={__import__('quash_plugins').__version__}"
    )
    assert registry.distribution_of("numpy.linalg") == f"numpy=={np.__version__}"
    assert registry.distribution_of(__name__) is None
    assert registry.distribution_of("__main__") is None


class _Sloppy(_Seeded):
    """Breaks the contract in ways the pipeline can mend: float64 rows of norm 2."""

    name = "sloppy"

    def encode_text(self, texts):
        return 2.0 * super().encode_text(texts).astype(np.float64)


def test_mended_output_is_warned_about_once_per_encoder(caplog):
    from quash_plugins.core import once
    from quash_plugins.core.text import encode_texts

    once.forget("encoder-contract")
    enc = _Sloppy()
    with caplog.at_level("WARNING", logger="quash_plugins.core.interfaces"):
        first = encode_texts(enc, ["chair", "sofa"], None)
        encode_texts(enc, ["table"], None)
    np.testing.assert_allclose(np.linalg.norm(first, axis=1), 1.0, rtol=1e-6)
    assert first.dtype == np.float32
    warned = [r.getMessage() for r in caplog.records]
    assert sum("returns float64 embeddings" in m for m in warned) == 1, warned
    assert sum("rows of norm up to 2" in m for m in warned) == 1, warned
    assert all("'sloppy'" in m and "check_encoder" in m for m in warned)


def test_an_encoder_configured_not_to_normalise_is_not_warned_about(caplog):
    from quash_plugins.core.text import encode_texts

    enc = _Sloppy()
    enc.name, enc.normalize = "sloppy-by-choice", False
    with caplog.at_level("WARNING", logger="quash_plugins.core.interfaces"):
        encode_texts(enc, ["chair"], None)
    assert not any("norm up to" in r.getMessage() for r in caplog.records)


def test_resolve_device_is_public_for_plugin_encoders():
    pytest.importorskip("torch")
    from quash_plugins.encoders import resolve_device

    assert resolve_device("auto") in ("cpu", "cuda", "mps")
    assert resolve_device("cpu") == "cpu"
    with pytest.raises(ConfigError, match="not a torch device"):
        resolve_device("tpu")


class _BatchNormed(_Seeded):
    """Normalises over the batch: a text's row depends on what it was embedded with."""

    name = "batch-normed"

    def encode_text(self, texts):
        from quash_plugins.testing import HashingEncoder

        e = HashingEncoder(8).encode_text(texts).astype(np.float64)
        if len(e) > 1:
            e = e - e.mean(axis=0)
        return (e / np.linalg.norm(e, axis=1, keepdims=True)).astype(np.float32)


class _Noisy(_Seeded):
    name = "noisy"

    def encode_text(self, texts):
        e = np.random.default_rng().normal(size=(len(texts), 8))
        return (e / np.linalg.norm(e, axis=1, keepdims=True)).astype(np.float32)


class _ListRows(_Seeded):
    """Returns a list of rows (``.tolist()``): the fix is np.asarray, not torch's."""

    name = "list-rows"

    def encode_text(self, texts):
        return super().encode_text(texts).tolist()


class _SqueezedOne(_Seeded):
    """Batch-independent, but squeezes the batch of one text to a (dim,) row."""

    name = "squeezed-one"

    def encode_text(self, texts):
        from quash_plugins.testing import HashingEncoder

        return HashingEncoder(8).encode_text(texts).squeeze()


@pytest.mark.parametrize(
    ("encoder", "check", "hint"),
    [
        (_BatchNormed(), "check_encoder_batch_independent", "normalise per text"),
        (_Noisy(), "check_encoder_deterministic", "from a fixed seed or from the text"),
        (_ListRows(), "check_encoder_output", "got builtins.list (return np.asarray(rows"),
        (_SqueezedOne(), "check_encoder_output", "shape (8,), expected (1, 8)"),
    ],
)
def test_the_kit_names_the_encoder_the_check_and_the_fix(encoder, check, hint, tmp_path):
    from quash_plugins.testing import check_encoder

    with pytest.raises(AssertionError) as err:
        check_encoder(encoder, tmp_path)
    msg = " ".join(str(err.value).split())
    assert msg.startswith(f"encoder {encoder.name!r}: {check}: "), msg
    assert hint in msg and "torch" not in msg


def test_the_batch_check_names_a_squeezed_row_not_the_batch(tmp_path):
    """A (dim,) row for one text was compared with a batch's row as if it were one: the
    check said 'an embedding must not depend on its batch', which is not the fault."""
    from quash_plugins.testing._checks import check_encoder_batch_independent

    with pytest.raises(AssertionError) as err:
        check_encoder_batch_independent(_SqueezedOne(), tmp_path)
    assert "shape (8,), expected (1, 8)" in str(err.value)
    assert "depend on its batch" not in str(err.value)


def test_the_kit_says_to_subclass_encoder_for_a_duck_typed_instance(tmp_path):
    """check_encoder on a class with dim and encode_text but no Encoder base said only
    'the plugin raised AttributeError: ... no attribute 'fingerprint''; it now says what
    the registry says."""
    from quash_plugins.testing import check_encoder

    class Duck:
        name = "duck"
        dim = 8

        def encode_text(self, texts):
            return _PrivateSeed().encode_text(texts)

    with pytest.raises(AssertionError) as err:
        check_encoder(Duck(), tmp_path)
    msg = str(err.value)
    assert msg == (
        "encoder 'duck' breaks the encoder interface: it lacks fingerprint. "
        "Subclass quash_plugins.Encoder."
    )


def _counting_encoder():
    from quash_plugins.testing import HashingEncoder

    class Counting(HashingEncoder):
        """A conformant encoder that counts its calls in a public attribute, without its
        own config(): its fingerprint would drift with use."""

        name = "counting"

        def __init__(self) -> None:
            super().__init__(dim=8)
            self.calls = 0

        def encode_text(self, texts):
            self.calls += 1
            return super().encode_text(texts)

        config = Encoder.config  # the default: public plain attributes

    return Counting()


def test_the_kit_catches_a_fingerprint_that_drifts_with_use(tmp_path):
    from quash_plugins.testing import HashingEncoder, check_encoder

    with pytest.raises(AssertionError, match="fingerprint\\(\\) changed after encode_text"):
        check_encoder(_counting_encoder(), tmp_path)
    check_encoder(HashingEncoder(8), tmp_path / "ok")


class _PrivateSeed(Encoder):
    """Conformant but for one thing: its seed lives in ``_seed`` and its config() does
    not name it, so two seeds share one fingerprint (and one cache)."""

    name = "private-seed"

    def __init__(self, dim: int = 8, seed: int = 0) -> None:
        self._dim = dim
        self._seed = seed

    @property
    def dim(self) -> int:
        return self._dim

    def encode_text(self, texts):
        from quash_plugins.testing import HashingEncoder

        return HashingEncoder(self._dim).encode_text([f"{self._seed} {t}" for t in texts])


def test_the_kit_catches_a_parameter_the_fingerprint_misses(tmp_path):
    """Before, the kit passed it, and the text cache served seed 0's embeddings to an
    encoder built with seed 1."""
    from quash_plugins.testing import check_encoder

    a, b = _PrivateSeed(seed=0), _PrivateSeed(seed=1)
    assert a.fingerprint() == b.fingerprint()
    assert not np.allclose(a.encode_text(["chair"]), b.encode_text(["chair"]))
    with pytest.raises(AssertionError) as err:
        check_encoder(_PrivateSeed(seed=1), tmp_path)
    msg = str(err.value)
    assert msg.startswith("encoder 'private-seed': check_encoder_fingerprint_follows_params:")
    assert "parameter 'seed'" in msg and "Return 'seed' from config()" in msg

    class Fixed(_PrivateSeed):
        def config(self):
            return {"dim": self._dim, "seed": self._seed}

    check_encoder(Fixed(seed=1), tmp_path / "ok")


class _UnseededProjection(_PrivateSeed):
    """Conformant within one instance, but its projection is drawn, unseeded, in
    ``__init__``: every instance (every process) embeds differently under one
    fingerprint."""

    name = "unseeded-projection"

    def __init__(self, dim: int = 8) -> None:
        super().__init__(dim)
        self._proj = np.random.default_rng().normal(size=(dim, dim))

    def encode_text(self, texts):
        e = super().encode_text(texts).astype(np.float64) @ self._proj
        return (e / np.linalg.norm(e, axis=1, keepdims=True)).astype(np.float32)


def test_the_kit_catches_an_encoder_that_differs_between_instances(tmp_path):
    """Before, the kit passed it (it compared one instance with itself), and a map built
    in one process was queried with other text embeddings in the next, under the same
    fingerprint (the text cache served one's rows to the other)."""
    from quash_plugins.testing import HashingEncoder, check_encoder

    with pytest.raises(AssertionError) as err:
        check_encoder(_UnseededProjection(), tmp_path)
    msg = " ".join(str(err.value).split())
    assert msg.startswith("encoder 'unseeded-projection': check_encoder_deterministic: ")
    assert "a second _UnseededProjection built with the same parameters" in msg
    assert "seed any random initialisation" in msg
    check_encoder(HashingEncoder(8), tmp_path / "ok")  # rebuilt, it embeds the same


class _TorchOut(_PrivateSeed):
    """Returns the torch tensor its model computed, still carrying gradients (as a GPU
    tensor, it could not be handed to numpy either)."""

    name = "torch-out"

    def config(self):
        return {"dim": self._dim, "seed": self._seed}

    def encode_text(self, texts):
        import torch

        rows = torch.from_numpy(super().encode_text(texts))
        return rows * torch.ones(1, requires_grad=True)


def test_a_torch_tensor_is_converted_with_a_warning_and_failed_by_the_kit(caplog, tmp_path):
    """Before: every query failed with torch's 'Can't call numpy() on Tensor that
    requires grad', naming no encoder, while the kit passed a CPU tensor."""
    pytest.importorskip("torch")
    from quash_plugins.core import once
    from quash_plugins.core.text import encode_texts
    from quash_plugins.testing import check_encoder

    once.forget("encoder-contract")
    enc = _TorchOut()
    with caplog.at_level("WARNING", logger="quash_plugins.core.interfaces"):
        got = encode_texts(enc, ["chair", "sofa"], None)
    assert got.dtype == np.float32 and got.shape == (2, 8)
    np.testing.assert_allclose(got, _PrivateSeed().encode_text(["chair", "sofa"]), atol=1e-6)
    warned = [r.getMessage() for r in caplog.records]
    assert any("'torch-out' returns a torch.Tensor, not a numpy array" in m for m in warned)
    with pytest.raises(
        AssertionError, match="check_encoder_output: encode_text must return a numpy"
    ):
        check_encoder(enc, tmp_path)


def test_a_list_of_rows_is_converted_with_a_warning_as_a_tensor_is(caplog):
    """``return rows.tolist()`` was taken silently, while float64, rows off unit norm and
    tensors each get a warning (and the kit fails all four)."""
    from quash_plugins.core import once
    from quash_plugins.core.text import encode_texts

    class Listed(_PrivateSeed):
        name = "listed"

        def encode_text(self, texts):
            return super().encode_text(texts).tolist()

    once.forget("encoder-contract")
    with caplog.at_level("WARNING", logger="quash_plugins.core.interfaces"):
        got = encode_texts(Listed(), ["chair", "sofa"], None)
    np.testing.assert_allclose(got, _PrivateSeed().encode_text(["chair", "sofa"]), atol=1e-6)
    warned = [r.getMessage() for r in caplog.records]
    assert any("'listed' returns a builtins.list of rows, not a numpy array" in m for m in warned)


class _NoReturn(_PrivateSeed):
    """Computes its rows and forgets to return them."""

    name = "no-return"

    def encode_text(self, texts):
        super().encode_text(texts)


def test_an_encode_text_that_returns_none_says_so(tmp_path):
    """Before, a query said 'returned shape () for 2 texts' (None read as a 0-d array),
    and the kit 'got builtins.NoneType (a torch tensor: ...)'."""
    from quash_plugins.core.errors import EncoderError
    from quash_plugins.core.text import encode_texts
    from quash_plugins.testing import check_encoder

    with pytest.raises(EncoderError) as err:
        encode_texts(_NoReturn(), ["chair", "sofa"], None)
    msg = str(err.value)
    assert msg.startswith("Encoder 'no-return' (") and "returned None for 2 texts" in msg
    assert "without a 'return'" in msg and "shape ()" not in msg
    with pytest.raises(AssertionError, match="check_encoder_output: encode_text returned None"):
        check_encoder(_NoReturn(), tmp_path)


def test_rows_that_are_not_an_array_name_the_encoder():
    from quash_plugins.core.errors import EncoderError
    from quash_plugins.core.text import encode_texts

    class Ragged(_PrivateSeed):
        name = "ragged"

        def encode_text(self, texts):
            return [[0.0, 1.0], [1.0]][: len(texts)]

    with pytest.raises(EncoderError, match="Encoder 'ragged' returned a builtins.list that is not"):
        encode_texts(Ragged(), ["chair", "sofa"], None)


@pytest.mark.parametrize(
    "rows, what",
    [
        (lambda n: np.ones((n, 3), np.float32), "returned shape (2, 3) for 2 texts"),
        (lambda n: np.ones((n, 8), np.float32).T, "returned shape (8, 2) for 2 texts"),
        (lambda n: np.full((n, 8), np.nan, np.float32), "returned NaN or Inf embeddings"),
        (lambda n: np.zeros((n, 8), np.float32), "returned a zero embedding for 'chair'"),
    ],
)
def test_output_that_breaks_the_contract_names_the_module_and_the_kit(rows, what):
    """A wrong shape, NaN or a zero row used to name the encoder only: now its module
    (and distribution, for an installed one) and the conformance check to run."""
    from quash_plugins.core.errors import EncoderError
    from quash_plugins.core.text import encode_texts

    class Broken(_PrivateSeed):
        name = "broken-output"

        def encode_text(self, texts):
            return rows(len(texts))

    with pytest.raises(EncoderError) as err:
        encode_texts(Broken(), ["chair", "sofa"], None)
    msg = str(err.value)
    assert msg.startswith(f"Encoder 'broken-output' ({__name__}) {what}")
    assert "quash_plugins.testing.check_encoder(encoder)" in msg


def test_an_error_inside_encode_text_names_the_encoder():
    """Before: the plugin's own exception reached the command line as an 'unexpected
    error' naming no encoder (a CUDA out-of-memory error, say)."""
    from quash_plugins.core.errors import EncoderError
    from quash_plugins.core.text import encode_texts

    class OutOfMemory(_PrivateSeed):
        name = "out-of-memory"

        def encode_text(self, texts):
            raise RuntimeError("CUDA out of memory")

    with pytest.raises(EncoderError) as err:
        encode_texts(OutOfMemory(), ["chair", "sofa"], None)
    msg = str(err.value)
    assert msg.startswith(f"Encoder 'out-of-memory' ({__name__}) failed to encode 2 strings")
    assert "RuntimeError: CUDA out of memory" in msg and "'encoder:' section" in msg
    assert isinstance(err.value.__cause__, RuntimeError)


def test_a_dependency_missing_inside_encode_text_names_the_distribution(monkeypatch):
    """A plugin importing its model library in encode_text: the error named the module
    only, and did not say to list the library in the plugin's dependencies, as the same
    import at module level or in __init__ does."""
    from quash_plugins.core import text
    from quash_plugins.core.errors import EncoderError

    class LazyImport(_PrivateSeed):
        name = "lazy-import"

        def encode_text(self, texts):
            import quash_test_no_such_model_lib  # noqa: F401

    monkeypatch.setattr(text, "distribution_of", lambda module: "acme-encoders==0.1.1")
    with pytest.raises(EncoderError) as err:
        text.encode_texts(LazyImport(), ["chair"], None)
    msg = str(err.value)
    assert msg.startswith(
        f"Encoder 'lazy-import' ({__name__}, distribution acme-encoders==0.1.1) failed"
    ), msg
    assert "'quash_test_no_such_model_lib', which is not installed" in msg
    assert msg.endswith("and list it in the dependencies of 'acme-encoders'.")


_PLUGIN_SOURCE = """
import numpy as np
from quash_plugins import Encoder


class Edited(Encoder):
    name = "edited"
    dim = 2

    def encode_text(self, texts):
        return np.tile(np.array([[ROW]], dtype=np.float32), (len(texts), 1))
"""


def _load_plugin(folder, module, row):
    """Write ``folder/module.py`` with ``encode_text`` returning ``row`` and import it
    afresh, as a new process would after the edit."""
    import importlib
    import os
    import sys

    path = folder / module / "__init__.py"
    path.parent.mkdir(parents=True, exist_ok=True)
    old = path.stat().st_mtime_ns if path.exists() else 0
    path.write_text(_PLUGIN_SOURCE.replace("ROW", row))
    os.utime(path, ns=(old + 10**9, old + 10**9))  # an edit within the same second
    sys.modules.pop(module, None)
    importlib.invalidate_caches()
    return importlib.import_module(module).Edited()


@pytest.mark.parametrize("install", ["none", "editable", "release", "wheel", "source-tree"])
def test_editing_encode_text_changes_the_fingerprint_unless_a_version_names_it(
    tmp_path, monkeypatch, install
):
    """The text cache is keyed by the fingerprint. A researcher iterating on a plugin in
    a script or a ``pip install -e`` checkout must not be served the rows cached before
    the edit (it used to be name + version + config only); a released install keeps its
    fingerprint, which its version names.

    ``source-tree``: run from the root of a flat-layout plugin project where an earlier
    ``pip install .`` left ``NAME.egg-info``: that metadata is found first, it has no
    ``direct_url.json``, and the source was taken for a released install, so an edit
    of ``encode_text`` was served the rows cached before it."""
    from quash_plugins.core.text import encode_texts
    from quash_plugins.engine import TextEmbeddingCache

    module = f"qp_edited_{install.replace('-', '_')}"
    monkeypatch.syspath_prepend(str(tmp_path))
    if install != "none":  # a dist-info as pip writes it (PEP 610 direct_url.json)
        info = tmp_path / f"{module}-1.0.dist-info"
        info.mkdir()
        info.joinpath("METADATA").write_text(
            f"Metadata-Version: 2.1\nName: {module}\nVersion: 1.0\n"
        )
        editable = "true" if install == "editable" else "false"
        info.joinpath("direct_url.json").write_text(
            f'{{"url": "file:///src", "dir_info": {{"editable": {editable}}}}}'
        )
    if install == "wheel":  # installed from a wheel: a RECORD and no direct_url.json
        info.joinpath("direct_url.json").unlink()
        info.joinpath("RECORD").write_text(f"{module}/__init__.py,,\n")
    if install == "source-tree":  # what setuptools' egg_info writes in the project
        info.rename(tmp_path / f"{module}.egg-info")
        info = tmp_path / f"{module}.egg-info"
        info.joinpath("METADATA").rename(info / "PKG-INFO")
        info.joinpath("direct_url.json").unlink()
        info.joinpath("SOURCES.txt").write_text(f"pyproject.toml\n{module}/__init__.py\n")
    cache = TextEmbeddingCache(tmp_path / "cache")
    before = _load_plugin(tmp_path, module, "1, 0")
    assert registry.distribution_of(module) == (None if install == "none" else f"{module}==1.0")
    fp = before.fingerprint()
    np.testing.assert_array_equal(encode_texts(before, ["chair"], cache), [[1, 0]])
    same = _load_plugin(tmp_path, module, "1, 0")  # rewritten, unchanged: same code
    assert same.fingerprint() == fp
    after = _load_plugin(tmp_path, module, "0, 1")
    if install in ("release", "wheel"):
        assert after.fingerprint() == fp
        return
    assert after.fingerprint() != fp
    np.testing.assert_array_equal(encode_texts(after, ["chair"], cache), [[0, 1]])


_HELPER_PLUGIN = """
import numpy as np
from quash_plugins import Encoder

from .helpers import row


class Edited(Encoder):
    name = "edited-helper"
    dim = 2

    def encode_text(self, texts):
        return np.tile(np.array([row()], dtype=np.float32), (len(texts), 1))
"""


def _load_helper_plugin(folder, module, row):
    """A package ``module`` whose encoder takes its row from ``module/helpers.py``
    (written to return ``row``), imported afresh."""
    import importlib
    import sys

    pkg = folder / module
    pkg.mkdir(parents=True, exist_ok=True)
    (pkg / "__init__.py").write_text(_HELPER_PLUGIN)
    (pkg / "helpers.py").write_text(f"def row():\n    return [{row}]\n")
    for name in (module, f"{module}.helpers"):
        sys.modules.pop(name, None)
    importlib.invalidate_caches()
    return importlib.import_module(module).Edited()


@pytest.mark.parametrize("bounded", [False, True])
def test_editing_a_helper_module_of_the_package_changes_the_fingerprint(
    tmp_path, monkeypatch, bounded
):
    """The encoder's own module is unchanged; the helper it imports changes what it
    returns. The package's every .py file is hashed, so the cache does not serve the
    rows of before the edit; a package over the bounds hashes the module file alone."""
    from quash_plugins.core import interfaces
    from quash_plugins.core.text import encode_texts
    from quash_plugins.engine import TextEmbeddingCache

    if bounded:
        monkeypatch.setattr(interfaces, "PACKAGE_DIGEST_MAX_FILES", 1)
    module = f"qp_helper_{int(bounded)}"
    monkeypatch.syspath_prepend(str(tmp_path))
    assert registry.distribution_of(module) is None  # a local package, no version
    cache = TextEmbeddingCache(tmp_path / "cache")
    before = _load_helper_plugin(tmp_path, module, "1, 0")
    fp = before.fingerprint()
    assert fp == before.fingerprint()  # computed once, the same each time
    np.testing.assert_array_equal(encode_texts(before, ["chair"], cache), [[1, 0]])
    assert _load_helper_plugin(tmp_path, module, "1, 0").fingerprint() == fp  # same code
    after = _load_helper_plugin(tmp_path, module, "0, 1")
    np.testing.assert_array_equal(after.encode_text(["chair"]), [[0, 1]])
    if bounded:  # only __init__.py is hashed: the edit is not seen
        assert after.fingerprint() == fp
        return
    assert after.fingerprint() != fp
    np.testing.assert_array_equal(encode_texts(after, ["chair"], cache), [[0, 1]])


def test_messages_name_the_plugin_a_factory_entry_point_was_registered_under(caplog):
    """A factory entry point (``fast-sloppy = pkg:make``) may build an instance of a class
    with another ``name``; the contract warnings and encoder errors named the class's
    ``'sloppy'``, a plugin the user never configured."""
    from quash_plugins.core import once
    from quash_plugins.core.errors import EncoderError
    from quash_plugins.core.text import encode_texts

    class _Failing(_Seeded):
        def encode_text(self, texts):
            raise RuntimeError("weights file unreadable")

    once.forget("encoder-contract")
    registry.register("encoders", "fast-sloppy", lambda: _Sloppy(), dist="tests")
    registry.register("encoders", "fast-failing", lambda: _Failing(), dist="tests")
    try:
        enc = registry.create("encoders", "fast-sloppy")
        assert enc.name == "sloppy"  # its own name still keys the cache
        with caplog.at_level("WARNING", logger="quash_plugins.core.interfaces"):
            encode_texts(enc, ["chair"], None)
        warned = [r.getMessage() for r in caplog.records]
        assert len(warned) == 2 and all("Encoder 'fast-sloppy' " in m for m in warned), warned
        with pytest.raises(EncoderError, match="^Encoder 'fast-failing' .*weights file"):
            encode_texts(registry.create("encoders", "fast-failing"), ["chair"], None)
    finally:
        registry.unregister("encoders", "fast-sloppy", dist="tests")
        registry.unregister("encoders", "fast-failing", dist="tests")


def test_a_built_in_encoder_hashes_its_own_subpackage_not_the_whole_project(monkeypatch):
    """In an editable checkout every commit edits some module of quash_plugins (the CLI,
    the viewer): hashing them all gave the built-in encoders a new fingerprint at every
    edit or pull, an empty text cache, and a "built with another embedding function"
    warning for every map built before. Their own subpackage is hashed instead."""
    from quash_plugins.core import interfaces
    from quash_plugins.encoders._table import TableEncoder

    monkeypatch.setattr(registry, "distribution_of", lambda module: None)  # unversioned
    asked = []
    monkeypatch.setattr(interfaces, "_package_digest", lambda p: asked.append(p) or "d")
    monkeypatch.setattr(interfaces, "_SOURCE_DIGESTS", interfaces.weakref.WeakKeyDictionary())
    assert interfaces.source_digest(TableEncoder) == "d"
    assert asked == ["quash_plugins.encoders"]
    assert interfaces.digest_package("my_plugin.nets.clip") == "my_plugin"
    assert interfaces.digest_package("quash_plugins.viewer._rerun") == "quash_plugins.viewer"
    assert interfaces.digest_package("quash_plugins.main") is None  # its module file


class _Lazy(_Seeded):
    """A plugin whose dim reads a model it loads on first encode (a common mistake)."""

    name = "lazy"
    _model = None

    @property
    def dim(self) -> int:
        return self._model.dim


class _Fractional(_Seeded):
    name = "fractional"

    @property
    def dim(self) -> float:
        return 8.5


@pytest.mark.parametrize(("cls", "why"), [(_Lazy, "AttributeError"), (_Fractional, "8.5")])
def test_an_encoder_whose_dim_fails_is_named_wherever_dim_is_read(cls, why):
    """quash query and make-scene said "unexpected error: AttributeError: 'NoneType' object
    has no attribute 'dim'" for a lazy plugin, naming no encoder; each place that reads dim
    now names the encoder, its module and the fix."""
    from quash_plugins import LatentMap
    from quash_plugins.core.errors import EncoderError
    from quash_plugins.core.text import encode_texts, encoder_dim
    from quash_plugins.engine.map_fit import check_encoder_fits

    enc = cls()
    lmap = LatentMap(embeddings=np.eye(3, 8, dtype=np.float32))
    for read in (
        encoder_dim,
        lambda e: encode_texts(e, ["chair"]),
        lambda e: check_encoder_fits(e, lmap),
    ):
        with pytest.raises(EncoderError) as info:
            read(enc)
        text = str(info.value)
        assert f"Encoder '{cls.name}'" in text and __name__ in text and why in text, text
        assert "set it in __init__" in text
    assert encoder_dim(_Seeded()) == 8


def test_the_kit_without_a_folder_leaves_none_behind(tmp_path, monkeypatch):
    """check_encoder(encoder), as docs/plugins.md runs it, left a quash-kit-* folder in
    the temporary directory on every call."""
    import tempfile

    from quash_plugins.testing import HashingEncoder, check_encoder

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    check_encoder(HashingEncoder(8))
    assert list(tmp_path.iterdir()) == []


class _PrivateSwitch(Encoder):
    """Conformant but for one thing: a switch that changes the output (pluralising)
    kept in ``_plural``, out of config() and so out of the fingerprint."""

    name = "private-switch"

    def __init__(self, dim: int = 8, plural: bool = True) -> None:
        self._dim = dim
        self._plural = plural

    @property
    def dim(self) -> int:
        return self._dim

    def encode_text(self, texts):
        from quash_plugins.testing import HashingEncoder

        return HashingEncoder(self._dim).encode_text(
            [f"{t}s" if self._plural else t for t in texts]
        )


def test_the_kit_catches_a_switch_the_fingerprint_misses(tmp_path):
    """Only numbers were varied: a boolean parameter that changes the output passed, and
    the text cache served one setting's embeddings to the other."""
    from quash_plugins.testing import check_encoder

    on, off = _PrivateSwitch(plural=True), _PrivateSwitch(plural=False)
    assert on.fingerprint() == off.fingerprint()
    with pytest.raises(AssertionError) as err:
        check_encoder(on, tmp_path)
    msg = str(err.value)
    assert msg.startswith("encoder 'private-switch': check_encoder_fingerprint_follows_params:")
    assert "parameter 'plural'" in msg and "plural=True and plural=False" in msg

    class Fixed(_PrivateSwitch):
        def config(self):
            return {"dim": self._dim, "plural": self._plural}

    check_encoder(Fixed(), tmp_path / "ok")


class _HashSeeded(Encoder):
    """Deterministic within one process, not across them: each text's vector is drawn
    from a generator seeded with Python's hash() of the text, which is salted per
    process. The most common way to write a toy encoder."""

    name = "hash-seeded"

    def __init__(self, dim: int = 8) -> None:
        self._dim = dim

    @property
    def dim(self) -> int:
        return self._dim

    def config(self):
        return {"dim": self._dim}

    def _seed(self, text: str) -> int:
        return hash(text) % 2**32

    def encode_text(self, texts):
        rows = [np.random.default_rng(self._seed(t)).normal(size=self._dim) for t in texts]
        out = np.asarray(rows, dtype=np.float32).reshape(len(texts), self._dim)
        return out / np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-12)


class _DigestSeeded(_HashSeeded):
    """The fix the message gives: a stable digest of the text."""

    name = "digest-seeded"

    def _seed(self, text: str) -> int:
        import zlib

        return zlib.crc32(text.encode("utf-8"))


def test_the_kit_catches_an_encoder_seeded_by_the_salted_hash(tmp_path):
    """Every other check runs in one process, where hash() is stable: such an encoder
    passed, and embedded differently in the next process (the map's, the cache's)."""
    from quash_plugins.testing import check_encoder
    from quash_plugins.testing._checks import check_encoder_same_in_another_process

    enc = _HashSeeded()
    assert np.allclose(enc.encode_text(["chair"]), _HashSeeded().encode_text(["chair"]))
    with pytest.raises(AssertionError) as err:
        check_encoder(enc, tmp_path)
    msg = str(err.value)
    assert msg.startswith("encoder 'hash-seeded': check_encoder_same_in_another_process:")
    assert "differs in another Python process" in msg and "instead of hash()" in msg
    check_encoder(_DigestSeeded(), tmp_path / "ok")

    # a class another process cannot import is not compared (nothing to build there)
    def local():
        class Local(_HashSeeded):
            pass

        return Local()

    check_encoder_same_in_another_process(local(), tmp_path / "local")


class _HashSeededFromFiles(_HashSeeded):
    """The same fault, built from a folder (a Path) and a numpy size, as conformance
    params written under tmp_path are: still built in the other process and compared."""

    name = "hash-seeded-files"

    def __init__(self, folder: Path = Path("."), dim: int = 8) -> None:
        self._folder = Path(folder)
        super().__init__(dim)

    def config(self):
        return {"folder": str(self._folder), "dim": int(self._dim)}


def test_the_other_process_is_given_paths_and_numpy_numbers(tmp_path):
    from quash_plugins.testing._checks import check_encoder_same_in_another_process

    enc = _HashSeededFromFiles(tmp_path, np.int64(8))
    with pytest.raises(AssertionError, match="differs in another Python process"):
        check_encoder_same_in_another_process(enc, tmp_path)


class _HashSeededWithKey(_HashSeeded):
    """An encoder with a credential among its parameters (a hosted model's API key)."""

    name = "hash-seeded-key"

    def __init__(self, api_key: str = "", dim: int = 8) -> None:
        self._api_key = api_key
        super().__init__(dim)


def test_the_other_process_gets_the_parameters_on_stdin_not_the_command_line(tmp_path, monkeypatch):
    """A process's command line is readable by every user of the machine: an encoder's
    API key must not be put on it (it was, inside the JSON spec)."""
    import subprocess

    from quash_plugins.testing._checks import check_encoder_same_in_another_process

    calls = []
    real = subprocess.run

    def spy(args, *a, **kw):
        calls.append((list(args), kw.get("input")))
        return real(args, *a, **kw)

    monkeypatch.setattr(subprocess, "run", spy)
    with pytest.raises(AssertionError, match="differs in another Python process"):
        check_encoder_same_in_another_process(_HashSeededWithKey("sk-not-on-argv"), tmp_path)
    [(argv, given)] = calls
    assert not any("sk-not-on-argv" in a for a in argv)
    assert "sk-not-on-argv" in given  # the other process still builds it with the key
