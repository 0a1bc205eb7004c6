"""A map records the parameters of the encoder that built it (``encoder_params``); the
dimension error and the fingerprint warning name them, and every writer that keeps the
encoder record keeps them."""

from __future__ import annotations

import json
import logging
import re

import numpy as np
import pytest
import yaml

from quash_plugins.adapters import write_npz_map
from quash_plugins.core import once, registry
from quash_plugins.core.errors import DimensionMismatchError
from quash_plugins.core.maps import read_map
from quash_plugins.core.types import LatentMap
from quash_plugins.demo.scene import SceneOptions, make_scene, write_scene
from quash_plugins.engine import map_fit
from quash_plugins.testing import HashingEncoder

OPTS = dict(rooms=1, voxel_size=0.25, room_size=4.0, extra_objects=0)
SECRET = "sk-test-0123456789abcdef"


class BagOfWords(HashingEncoder):
    """A third-party-like encoder: ``dim`` and ``salt`` change its output; ``api_key``
    and ``options`` (with a credential inside) are what a plugin may also keep."""

    name = "bag-of-words"

    def __init__(self, dim: int = 32, salt: str = "", api_key: str | None = None) -> None:
        super().__init__(dim)
        self.salt = salt
        self.api_key = api_key

    def _word(self, word):
        return super()._word(self.salt + word)

    def config(self):
        return {
            "dim": self._dim,
            "salt": self.salt,
            "api_key": self.api_key,
            "sha": "not-a-parameter",  # config() may name more than __init__ takes
        }


@pytest.fixture
def bag_of_words():
    registry.register("encoders", "bag-of-words", BagOfWords, dist="pkg-bow")
    once.forget("built-by")
    try:
        yield lambda **params: registry.create("encoders", "bag-of-words", **params)
    finally:
        registry.unregister("encoders", "bag-of-words", dist="pkg-bow")


def _scene(encoder, path):
    return write_scene(make_scene(encoder, SceneOptions(**OPTS)), path)["map"]


def _without(path, key, out):
    """A copy of the NPZ at ``path`` without array ``key`` (a map written before it)."""
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files if k != key}
    np.savez(out, **arrays)
    return out


def _quoted_entry(msg: str) -> dict:
    """The ``encoder:`` entry a message tells the user to write, read as YAML."""
    [entry] = re.findall(r"'encoder: (\{.*?\})'", msg)
    return yaml.safe_load(entry)


def test_make_scene_records_the_parameters_and_an_npz_copy_keeps_them(bag_of_words, tmp_path):
    enc = bag_of_words(dim=64, salt="s1", api_key=SECRET)
    path = _scene(enc, tmp_path / "s.npz")
    lmap = read_map(path)
    assert lmap.source["encoder"] == "bag-of-words"
    assert lmap.source["encoder_fingerprint"] == enc.fingerprint()
    # what it was built with, less what __init__ does not take and the credential
    assert json.loads(lmap.source["encoder_params"]) == {"dim": enc.dim, "salt": enc.salt}
    copy = read_map(write_npz_map(lmap, tmp_path / "copy.npz"))
    assert copy.source["encoder_params"] == lmap.source["encoder_params"]


def test_no_secret_named_parameter_is_recorded(bag_of_words, tmp_path):
    enc = bag_of_words(dim=16, api_key=SECRET)
    path = _scene(enc, tmp_path / "s.npz")
    with np.load(path) as z:
        stored = "".join(str(z[k]) for k in z.files if z[k].dtype.kind == "U")
    assert SECRET not in stored and "api_key" not in stored
    assert "api_key" not in json.loads(read_map(path).source["encoder_params"])

    from quash_plugins.core.encoder_record import encoder_params

    class Nested(BagOfWords):
        def config(self):
            return {"dim": self._dim, "salt": {"auth_token": SECRET, "seed": 1}}

    nested = encoder_params(Nested(8))
    assert SECRET not in json.dumps(nested)
    assert nested["dim"] == 8


def test_the_vlmaps_writer_keeps_the_parameters(bag_of_words, tmp_path):
    pytest.importorskip("h5py")
    from quash_plugins.adapters._vlmaps_write import write_vlmaps_map

    path = _scene(bag_of_words(dim=64, salt="v"), tmp_path / "s.npz")
    src = read_map(path)
    h5 = write_vlmaps_map(src, tmp_path / "vl")
    back = read_map(h5)
    for key in ("encoder", "encoder_fingerprint", "encoder_params"):
        assert back.source[key] == src.source[key]
    assert json.loads(back.source["encoder_params"])["dim"] == 64


def test_the_openlex3d_export_keeps_the_parameters(bag_of_words, tmp_path):
    from quash_plugins.adapters._openlex3d import write_openlex3d_map

    src = read_map(_scene(bag_of_words(dim=64, salt="o"), tmp_path / "s.npz"))
    out = write_openlex3d_map(src, tmp_path / "ol3d")
    back = read_map(out, adapter="openlex3d")
    assert back.source["encoder_params"] == src.source["encoder_params"]


def test_the_dimension_error_writes_the_recorded_entry(bag_of_words, tmp_path):
    """Built with 'bag-of-words' dim 64, queried with its default (32): the fix is the
    config entry with the recorded parameters, which builds an encoder that fits."""
    built = bag_of_words(dim=64, salt="s1")
    lmap = read_map(_scene(built, tmp_path / "s.npz"))
    with pytest.raises(DimensionMismatchError) as err:
        map_fit.check_encoder_fits(bag_of_words(), lmap)
    msg = str(err.value)
    assert "Write 'encoder: {name: bag-of-words, dim: 64, salt: s1}'" in msg
    entry = _quoted_entry(msg)
    name = entry.pop("name")
    fixed = registry.create("encoders", name, **entry)
    assert fixed.dim == lmap.dim and fixed.fingerprint() == built.fingerprint()
    map_fit.check_encoder_fits(fixed, lmap)  # fits, and warns of nothing


def test_the_dimension_error_names_the_other_encoders_parameters(bag_of_words, tmp_path):
    """A map built by 'bag-of-words' queried with another (registered-name) encoder: the
    fix names the map's encoder with its parameters."""
    lmap = read_map(_scene(bag_of_words(dim=64), tmp_path / "s.npz"))
    with pytest.raises(DimensionMismatchError) as err:
        map_fit.check_encoder_fits(HashingEncoder(16), lmap)
    msg = str(err.value)
    assert "records that encoder 'bag-of-words' built it" in msg
    assert _quoted_entry(msg) == {"name": "bag-of-words", "dim": 64, "salt": ""}


def test_the_warning_names_the_parameter_that_differs(bag_of_words, tmp_path, caplog):
    lmap = read_map(_scene(bag_of_words(dim=32, salt="s1"), tmp_path / "s.npz"))
    with caplog.at_level(logging.WARNING, logger="quash_plugins.engine.map_fit"):
        map_fit.check_encoder_fits(bag_of_words(dim=32, salt="s2"), lmap)
    [msg] = [r.getMessage() for r in caplog.records if "was built with encoder" in r.getMessage()]
    assert "The parameters that differ: salt: s1 (the map) vs s2 (this config)" in msg
    assert "dim:" not in msg.split("differ:")[1].split("Scores")[0]  # dim is the same
    assert _quoted_entry(msg) == {"name": "bag-of-words", "dim": 32, "salt": "s1"}


def test_the_warning_says_when_the_parameters_are_the_same(bag_of_words, tmp_path, caplog):
    """Same parameters, another fingerprint (its code, its release): the parameters are
    not what to change, so no entry is offered."""
    enc = bag_of_words(dim=32, salt="s1")
    lmap = read_map(_scene(enc, tmp_path / "s.npz"))
    lmap.source["encoder_fingerprint"] = "bag-of-words-0"  # as if built by older code
    with caplog.at_level(logging.WARNING, logger="quash_plugins.engine.map_fit"):
        map_fit.check_encoder_fits(enc, lmap)
    [msg] = [r.getMessage() for r in caplog.records if "was built with encoder" in r.getMessage()]
    assert "The parameters the map records ({name: bag-of-words, dim: 32, salt: s1})" in msg
    assert "are this config's" in msg and "'encoder: {" not in msg


def test_an_old_map_without_the_parameters_works_as_before(bag_of_words, tmp_path, caplog):
    path = _scene(bag_of_words(dim=64, salt="s1"), tmp_path / "s.npz")
    old = read_map(_without(path, "encoder_params", tmp_path / "old.npz"))
    assert "encoder_params" not in old.source
    assert old.source["encoder"] == "bag-of-words"
    with pytest.raises(DimensionMismatchError) as err:
        map_fit.check_encoder_fits(HashingEncoder(16), old)
    assert "write 'encoder: bag-of-words' with the parameters the map was built with" in str(
        err.value
    )
    with caplog.at_level(logging.WARNING, logger="quash_plugins.engine.map_fit"):
        map_fit.check_encoder_fits(bag_of_words(dim=64, salt="s2"), old)
    [msg] = [r.getMessage() for r in caplog.records if "was built with encoder" in r.getMessage()]
    assert "under the same encoder name" in msg and "parameters that differ" not in msg


def test_bad_json_in_the_record_is_ignored(bag_of_words, tmp_path, caplog):
    path = _scene(bag_of_words(dim=64), tmp_path / "s.npz")
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    for bad in ("{not json", "[64]", ""):
        arrays["encoder_params"] = np.asarray(bad)
        np.savez(tmp_path / "bad.npz", **arrays)
        with caplog.at_level(logging.DEBUG, logger="quash_plugins.core.encoder_record"):
            lmap = read_map(tmp_path / "bad.npz")
        assert "encoder_params" not in lmap.source
        assert lmap.source["encoder"] == "bag-of-words"  # the rest of the record stays
    assert any("encoder_params" in r.getMessage() for r in caplog.records)
    # a source made by hand (or a Zarr store's) that holds bad JSON: the message falls back
    hand = LatentMap(lmap.embeddings, source=dict(lmap.source, encoder_params="{oops"))
    with pytest.raises(DimensionMismatchError, match="with the parameters the map was built"):
        map_fit.check_encoder_fits(HashingEncoder(16), hand)


def test_parameters_that_never_change_the_output_are_not_recorded():
    """device and batch_size (docs/plugins.md: output-neutral) would only add noise to
    the entry a dimension error tells the user to write."""
    from quash_plugins.core.encoder_record import OUTPUT_NEUTRAL, encoder_params

    class Batched(BagOfWords):
        def __init__(self, dim: int = 8, batch_size: int = 32, device: str = "cpu"):
            super().__init__(dim)
            self.batch_size, self.device = batch_size, device

        def config(self):
            return {"dim": self._dim, "batch_size": self.batch_size, "device": self.device}

    assert set(OUTPUT_NEUTRAL) == {"device", "batch_size"}
    assert encoder_params(Batched(dim=12, batch_size=7)) == {"dim": 12}


def test_a_non_finite_parameter_counts_in_the_fingerprint_but_is_not_recorded():
    """One plain-data rule (core.interfaces._plain) serves both: config() keeps NaN and
    infinity (they change the output, so the fingerprint), the map's JSON record drops
    them (JSON has no NaN), nested in a list too."""
    from quash_plugins.core.encoder_record import encoder_params

    class Scaled(BagOfWords):
        def __init__(self, dim: int = 8, salt: str = "", scale=1.0, ranges=None):
            super().__init__(dim, salt)
            self.scale, self.ranges = scale, ranges

        def config(self):
            return {"dim": self._dim, "scale": self.scale, "ranges": self.ranges}

    odd = Scaled(scale=float("inf"), ranges=[0.5, float("nan")])
    assert encoder_params(odd) == {"dim": 8}
    assert encoder_params(Scaled(scale=2.0, ranges=[0.5, 1.0])) == {
        "dim": 8,
        "scale": 2.0,
        "ranges": [0.5, 1.0],
    }
    assert odd.fingerprint() != Scaled(scale=2.0).fingerprint()
