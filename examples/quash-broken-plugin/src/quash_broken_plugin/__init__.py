"""Deliberately broken plugins, one per mistake a plugin author makes. Used only by
quash-plugins' tests, which check that each is reported with what to fix while every
other plugin keeps working:

* ``broken-encoder``: importing ``BrokenEncoder`` fails (a dependency is not installed);
* ``typo-module``, ``typo-object``: entry points that name a module or an object that
  does not exist;
* ``not-a-classifier``: a class with none of the classifier interface;
* ``half-encoder``: an ``Encoder`` subclass that never implements ``encode_text``;
* ``needs-a-library``: imports a library that is not installed when it is built;
* ``lazy-library``: imports it on first use, inside ``encode_text``;
* ``an-instance``: an entry point that names an instance, not its class.
"""

import importlib

import numpy as np

from quash_plugins import Encoder

MISSING = "a_dependency_that_is_not_installed"


class NotAClassifier:
    """Has no fit/decision_function: the registry must reject it."""


class HalfEncoder(Encoder):
    """Declares its dimension but not ``encode_text``."""

    @property
    def dim(self) -> int:
        return 8


class NeedsALibrary(Encoder):
    """Imports its model library in ``__init__``."""

    def __init__(self) -> None:
        importlib.import_module(MISSING)

    @property
    def dim(self) -> int:
        return 8

    def encode_text(self, texts):  # pragma: no cover - never built
        return np.zeros((len(texts), 8), np.float32)


class LazyLibrary(Encoder):
    """Imports its model library on first use, as docs/plugins.md recommends."""

    @property
    def dim(self) -> int:
        return 8

    def encode_text(self, texts):
        importlib.import_module(MISSING)
        raise AssertionError("unreachable")


#: An instance where the entry point must name the class (or a factory).
AN_INSTANCE = LazyLibrary()


def __getattr__(name):
    if name == "BrokenEncoder":
        importlib.import_module(MISSING)
    raise AttributeError(name)
