"""A map records the encoder that built it; a query with another encoder is warned about."""

from __future__ import annotations

import numpy as np

from quash_plugins import Quash
from quash_plugins.adapters import write_npz_map
from quash_plugins.core import once
from quash_plugins.core.maps import read_map
from quash_plugins.demo.scene import SceneOptions, make_scene, write_scene
from quash_plugins.testing import HashingEncoder

OPTS = dict(rooms=1, voxel_size=0.25, room_size=4.0, extra_objects=0)


class _OtherHashing(HashingEncoder):
    """Same dimension, another embedding function (what a dimension check cannot see)."""

    name = "other-hashing"

    def _word(self, word):
        return super()._word(word[::-1])


def _quash(encoder):
    q = Quash.from_config({"heuristic": "none", "classifier": "contrast", "cache": False})
    q.encoder = encoder
    return q


def test_the_map_records_its_encoder_and_a_copy_keeps_it(tmp_path):
    enc = HashingEncoder(32)
    paths = write_scene(make_scene(enc, SceneOptions(**OPTS)), tmp_path / "s.npz")
    lmap = read_map(paths["map"])
    assert lmap.source["encoder"] == "hashing-test"
    assert lmap.source["encoder_fingerprint"] == enc.fingerprint()
    copy = write_npz_map(lmap, tmp_path / "copy.npz")
    assert read_map(copy).source["encoder_fingerprint"] == enc.fingerprint()


def test_the_map_records_the_name_a_config_writes(tmp_path):
    """Before: make-scene recorded the class's ``name``; an encoder built by a factory
    entry point ('reversed-words') of a class named otherwise was recorded under a name
    no config can write, and the dimension error's advice named it."""
    from quash_plugins.core import registry

    registry.register("encoders", "reversed-words", lambda: _OtherHashing(32), dist="pkg-rev")
    try:
        encoder = registry.create("encoders", "reversed-words")
    finally:
        registry.unregister("encoders", "reversed-words", dist="pkg-rev")
    paths = write_scene(make_scene(encoder, SceneOptions(**OPTS)), tmp_path / "s.npz")
    lmap = read_map(paths["map"])
    assert lmap.source["encoder"] == "reversed-words"
    assert lmap.source["encoder_fingerprint"] == encoder.fingerprint()


def test_a_query_with_another_encoder_warns_once_and_the_same_one_never(tmp_path, caplog):
    paths = write_scene(make_scene(HashingEncoder(32), SceneOptions(**OPTS)), tmp_path / "s.npz")
    once.forget("built-by")
    with caplog.at_level("WARNING", logger="quash_plugins.engine.map_fit"):
        _quash(HashingEncoder(32)).query(str(paths["map"]), "chair")
        assert not [r for r in caplog.records if "was built with encoder" in r.getMessage()]
        other = _quash(_OtherHashing(32))
        other.query(str(paths["map"]), "chair")
        other.query(str(paths["map"]), "table")
    warned = [r.getMessage() for r in caplog.records if "was built with encoder" in r.getMessage()]
    assert len(warned) == 1, warned
    assert "'hashing-test'" in warned[0] and "'other-hashing'" in warned[0]
    assert str(paths["map"]) in warned[0]


def test_a_map_without_the_record_is_not_warned_about(tmp_path, caplog):
    from quash_plugins.core.types import LatentMap

    rng = np.random.default_rng(0)
    emb = rng.normal(size=(20, 32)).astype(np.float32)
    path = write_npz_map(LatentMap(emb, kind="points"), tmp_path / "m.npz")
    assert "encoder_fingerprint" not in np.load(path).files
    with caplog.at_level("WARNING", logger="quash_plugins.engine.map_fit"):
        _quash(_OtherHashing(32)).query(str(path), "chair")
    assert not [r for r in caplog.records if "was built with encoder" in r.getMessage()]


def test_the_warning_names_the_encoder_as_the_config_does(tmp_path, caplog):
    """An encoder built by a factory entry point under another name than its class's
    ``name`` is named by its registered name, as the config writes it (and as the
    dimension error names it), not by the instance's ``name``."""
    from quash_plugins.core import registry

    paths = write_scene(make_scene(HashingEncoder(32), SceneOptions(**OPTS)), tmp_path / "s.npz")
    registry.register("encoders", "reversed-words", lambda: _OtherHashing(32), dist="pkg-rev")
    try:
        encoder = registry.create("encoders", "reversed-words")
    finally:
        registry.unregister("encoders", "reversed-words", dist="pkg-rev")
    assert encoder.name == "other-hashing"  # the instance's own name differs
    once.forget("built-by")
    with caplog.at_level("WARNING", logger="quash_plugins.engine.map_fit"):
        _quash(encoder).query(str(paths["map"]), "chair")
    warned = [r.getMessage() for r in caplog.records if "was built with encoder" in r.getMessage()]
    assert len(warned) == 1, warned
    assert "this config's encoder is 'reversed-words'" in warned[0]
    assert "'other-hashing'" not in warned[0]  # (its fingerprint may spell it, unquoted)


class _DimHashing(HashingEncoder):
    """Another embedding function that, like many plugins, takes ``dim``."""

    name = "dim-hashing"

    def __init__(self, dim: int = 24) -> None:
        super().__init__(dim)


def test_a_dimension_mismatch_names_the_encoder_the_map_records(tmp_path, caplog):
    """Before: a map built by 'hashing-test' (32-d) queried with a 24-d encoder that takes
    ``dim`` was told to set that encoder's dim to 32, which gives rows of the right
    length in another space, and the encoder the map records came only in a warning
    logged before the error. Now the error names it, and the warning is not repeated."""
    import pytest

    from quash_plugins.core.errors import DimensionMismatchError

    paths = write_scene(make_scene(HashingEncoder(32), SceneOptions(**OPTS)), tmp_path / "s.npz")
    once.forget("built-by")
    with (
        caplog.at_level("WARNING", logger="quash_plugins.engine.map_fit"),
        pytest.raises(DimensionMismatchError) as err,
    ):
        _quash(_DimHashing(24)).query(str(paths["map"]), "chair")
    msg = str(err.value)
    assert "32-dimensional embeddings" in msg and "produces 24-dimensional" in msg
    assert "The map records that encoder 'hashing-test' built it" in msg
    assert "dim: 32" not in msg
    # 'hashing-test' is no registered name, so a config cannot write it: no such advice.
    assert "encoder: hashing-test" not in msg and "query with it" in msg
    assert not [r for r in caplog.records if "was built with encoder" in r.getMessage()]
    from quash_plugins.core import registry

    registry.register("encoders", "hashing-test", HashingEncoder, dist="pkg-hash")
    try:
        with pytest.raises(DimensionMismatchError) as err:
            _quash(_DimHashing(24)).query(str(paths["map"]), "chair")
    finally:
        registry.unregister("encoders", "hashing-test", dist="pkg-hash")
    # the map records the parameters it was built with: the entry to write, in full
    assert "write 'encoder: {name: hashing-test, dim: 32}'" in str(err.value)
    # The same encoder at another size: the map's own encoder, so its dim is the fix.
    same = HashingEncoder(16)
    with pytest.raises(DimensionMismatchError) as err:
        _quash(same).query(str(paths["map"]), "chair")
    assert "records that encoder" not in str(err.value)


def test_the_warning_says_an_edit_counts_for_an_encoder_whose_source_is_hashed(caplog, monkeypatch):
    """A plugin author iterating on an editable install edits any file of the package
    (a docstring, a new heuristic module): the fingerprint changes, and a map built the
    day before was warned about as 'other weights, another model or other settings',
    which sent them looking for a weights change. The warning now names the edit."""
    from quash_plugins.core.interfaces import source_digest
    from quash_plugins.core.types import LatentMap
    from quash_plugins.engine import map_fit

    enc = HashingEncoder(16)
    assert source_digest(type(enc)) is not None  # this checkout, or a test module
    rng = np.random.default_rng(0)
    emb = rng.normal(size=(20, 16)).astype(np.float32)
    source = {"path": "built.npz", "encoder": enc.name, "encoder_fingerprint": "hashing-test-0"}
    lmap = LatentMap(emb, kind="points", source=source)

    def warned():
        return [r.getMessage() for r in caplog.records if "was built with" in r.getMessage()]

    once.forget("built-by")
    with caplog.at_level("WARNING", logger="quash_plugins.engine.map_fit"):
        map_fit.check_encoder_fits(enc, lmap)
    assert len(warned()) == 1 and "another embedding function" in warned()[0]
    assert "is an editable install or a local module" in warned()[0]
    # A released install: its version names its code, so no edit to speak of.
    caplog.clear()
    once.forget("built-by")
    monkeypatch.setattr(map_fit, "source_digest", lambda cls: None)
    with caplog.at_level("WARNING", logger="quash_plugins.engine.map_fit"):
        map_fit.check_encoder_fits(enc, lmap)
    assert len(warned()) == 1 and "editable install" not in warned()[0]
    assert "another release" not in warned()[0]  # the built-in: the package's own version
    # A released third-party plugin: upgrading it changes the fingerprint, and says so
    from quash_plugins.core import registry

    class Plugin(HashingEncoder):
        pass

    Plugin.__module__ = "acme_encoders.hashing"
    monkeypatch.setattr(registry, "distribution_of", lambda module: "acme-encoders==0.1.1")
    caplog.clear()
    once.forget("built-by")
    with caplog.at_level("WARNING", logger="quash_plugins.engine.map_fit"):
        map_fit.check_encoder_fits(Plugin(16), lmap)
    assert "another release of its distribution (now acme-encoders==0.1.1)" in warned()[0]


def test_a_plugin_that_shadows_the_maps_encoder_is_named_as_the_config_names_it(tmp_path, caplog):
    """A map built by the built-in 'hashing-test', queried with another distribution's
    plugin of that name ('pkg-shadow:hashing-test'): the warning named the config's
    encoder 'hashing-test' and called it the same encoder with other settings. And a
    dimension error on such a map warned that 'hashing-test' is shadowed, although the
    config did not use that name."""
    import pytest

    from quash_plugins.core import registry
    from quash_plugins.core.errors import DimensionMismatchError

    paths = write_scene(make_scene(HashingEncoder(32), SceneOptions(**OPTS)), tmp_path / "s.npz")
    registry.register("encoders", "hashing-test", HashingEncoder, dist="quash-plugins")
    registry.register("encoders", "hashing-test", _OtherHashing, dist="pkg-shadow")
    try:
        shadow = registry.create("encoders", "pkg-shadow:hashing-test", dim=32)
        once.forget("built-by")
        with caplog.at_level("WARNING", logger="quash_plugins"):
            _quash(shadow).query(str(paths["map"]), "chair")
        warned = [r.getMessage() for r in caplog.records]
        built = [m for m in warned if "was built with encoder" in m]
        assert len(built) == 1, warned
        assert "this config's encoder is 'pkg-shadow:hashing-test'" in built[0]
        assert "under the same encoder name" not in built[0]
        caplog.clear()
        once.forget("registry")  # a shadow warning given before is given again
        with (
            caplog.at_level("WARNING", logger="quash_plugins"),
            pytest.raises(DimensionMismatchError, match=r"write 'encoder: \{name: hashing-test, "),
        ):
            _quash(_DimHashing(24)).query(str(paths["map"]), "chair")
        assert not [r for r in caplog.records if "also claimed by" in r.getMessage()]
    finally:
        registry.unregister("encoders", "hashing-test", dist="quash-plugins")
        registry.unregister("encoders", "hashing-test", dist="pkg-shadow")


def test_a_map_built_by_the_qualified_name_is_the_same_encoder_as_the_bare_name(tmp_path, caplog):
    """`quash make-scene --encoder my-dist:name` records 'my-dist:name'; a config that
    writes the bare name builds the same plugin. Its dimension error told the user to
    write 'encoder: my-dist:name' "with the parameters the map was built with" (which no
    file records) instead of the dim to set, and a fingerprint warning called it another
    encoder rather than the same one with other settings."""
    import pytest

    from quash_plugins.core import registry
    from quash_plugins.core.errors import DimensionMismatchError
    from quash_plugins.engine import map_fit

    registry.register("encoders", "dim-hashing", _DimHashing, dist="pkg-dim")
    try:
        built = registry.create("encoders", "pkg-dim:dim-hashing", dim=32)
        paths = write_scene(make_scene(built, SceneOptions(**OPTS)), tmp_path / "s.npz")
        lmap = read_map(paths["map"])
        assert lmap.source["encoder"] == "pkg-dim:dim-hashing"
        bare = registry.create("encoders", "dim-hashing")  # dim 24
        with pytest.raises(DimensionMismatchError) as err:
            map_fit.check_encoder_fits(bare, lmap)
        assert "'encoder: {name: dim-hashing, dim: 32}'" in str(err.value)
        assert "records that encoder" not in str(err.value)
        # the distribution as its import name spells it is the same plugin, as the
        # registry resolves it (pkg_dim:dim-hashing builds pkg-dim's encoder)
        lmap.source["encoder"] = "pkg_dim:dim-hashing"
        with pytest.raises(DimensionMismatchError) as err:
            map_fit.check_encoder_fits(bare, lmap)
        assert "'encoder: {name: dim-hashing, dim: 32}'" in str(err.value)
        lmap.source["encoder"] = "pkg-dim:dim-hashing"
        lmap.source["encoder_fingerprint"] = "dim-hashing-0"  # built with other settings
        once.forget("built-by")
        with caplog.at_level("WARNING", logger="quash_plugins.engine.map_fit"):
            map_fit.check_encoder_fits(registry.create("encoders", "dim-hashing", dim=32), lmap)
    finally:
        registry.unregister("encoders", "dim-hashing", dist="pkg-dim")
    warned = [r.getMessage() for r in caplog.records if "was built with encoder" in r.getMessage()]
    assert len(warned) == 1 and "under the same encoder name" in warned[0], warned
