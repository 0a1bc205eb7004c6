"""Conformance kit: the checks every encoder, heuristic, classifier and adapter must pass.

In the spirit of scikit-learn's ``parametrize_with_checks``. A plugin author runs the
whole kit over their distribution's plugins in one line::

    from . import parametrize_with_checks

    @parametrize_with_checks(dist="my-quash-plugin")
    def test_conformance(check, tmp_path):
        check(tmp_path)

Classifiers also run scikit-learn's own ``check_estimator`` (binary targets, as the
:class:`~quash_plugins.core.interfaces.Classifier` tags declare). A check a decision
rule cannot pass by design is declared, with its reason, by a method
``expected_failed_checks(self) -> {check_name: reason}``; a declared check that passes
fails the kit, so the list stays true.

A classifier implementing ``StackableClassifier`` or ``CosineClassifier`` is scored by
the engine from its expansion, so :func:`check_classifier_expansions` checks that the
expansion gives what ``decision_function`` gives.

Plugins that need parameters to be built (a file, a URL...) provide a classmethod
``conformance_params(tmp_path) -> dict`` returning working parameters; plugins that
cannot run offline may set ``conformance_skip = "reason"``.
"""

from __future__ import annotations

from ._checks import (
    HashingEncoder,
    PluginCheck,
    check_adapter,
    check_classifier,
    check_classifier_expansions,
    check_encoder,
    check_heuristic,
    check_plugin,
    expected_failed_checks,
    plugin_checks,
)

__all__ = [
    "HashingEncoder",
    "PluginCheck",
    "check_adapter",
    "check_classifier",
    "check_classifier_expansions",
    "check_encoder",
    "check_heuristic",
    "check_plugin",
    "expected_failed_checks",
    "parametrize_with_checks",
    "plugin_checks",
]


def parametrize_with_checks(
    kinds: str | list[str] | None = None,
    names: list[str] | None = None,
    dist: str | None = None,
):
    """A ``pytest.mark.parametrize`` over every (plugin, check) pair selected.

    The decorated test receives ``check``, a :class:`PluginCheck`; call it with a
    temporary directory: ``check(tmp_path)``.
    """
    import pytest

    checks = plugin_checks(kinds=kinds, names=names, dist=dist)
    if not checks:
        from ._checks import misplaced_hint, near_hint

        # installed, but in a group quash-plugins does not read: say so, not "installed?";
        # else the names nearest to a misspelt one
        hint = misplaced_hint(kinds, names, dist) or near_hint(kinds, names, dist)
        raise LookupError(
            f"No registered plugins match kinds={kinds!r}, names={names!r}, dist={dist!r}. "
            + (hint or "Is the distribution installed (pip install -e .)?")
        )
    return pytest.mark.parametrize("check", checks, ids=[c.id for c in checks])
