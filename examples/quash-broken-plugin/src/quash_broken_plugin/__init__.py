"""Deliberately broken: importing ``BrokenEncoder`` fails, ``NotAClassifier`` breaks the
classifier interface. Used only by quash-plugins' tests."""

import importlib


class NotAClassifier:
    """Has no fit/decision_function: the registry must reject it."""


def __getattr__(name):
    if name == "BrokenEncoder":
        importlib.import_module("a_dependency_that_is_not_installed")
    raise AttributeError(name)
