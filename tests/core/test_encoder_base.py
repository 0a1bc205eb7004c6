"""The Encoder base class: what its default config() and fingerprint() record."""

from __future__ import annotations

import numpy as np

from quash_plugins import Encoder
from quash_plugins.core import registry


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
