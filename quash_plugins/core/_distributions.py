"""Which installed distribution provides a module, and whether it is an editable install.

Private to :mod:`quash_plugins.core`; the public names are re-exported by
:mod:`quash_plugins.core.registry` (``distribution_of``, ``is_editable``,
``distribution_is_editable``, ``note_distribution``), whose plugin provenance, encoder
fingerprints and ``quash plugins`` listing use them.
"""

from __future__ import annotations

from typing import Any

#: Top-level module -> ``"name==version"``, noted by the registry from the entry points
#: it scans (a distribution's import name need not be its name).
_DISTRIBUTIONS: dict[str, str] = {}


def note_distribution(module: str, dist: str, version: str) -> None:
    """Record that ``module``'s top-level package comes from ``dist`` at ``version``.

    ``module`` may be an entry point's value, whose object follows a colon
    (``"acme:AcmeText"``, ``"acme.text:AcmeText"``): its top-level package is ``acme``.

    >>> note_distribution("acme_doc:AcmeText", "acme-vision-encoders", "1.0")
    >>> distribution_of("acme_doc.text")
    'acme-vision-encoders==1.0'
    """
    top = module.partition(":")[0].strip().partition(".")[0]
    _DISTRIBUTIONS[top] = f"{dist}=={version}"


_LOOKED_UP: dict[str, str | None] = {}


def distribution_of(module: str) -> str | None:
    """``"name==version"`` of the installed distribution providing ``module``, else None.

    Known from the plugin entry points the registry scanned, else looked up: the
    distribution whose files hold the top-level package (``acme`` installed by
    ``acme-vision-encoders``), else the distribution named as the package. None for a
    module that no distribution installed (a script, a test file).

    Examples
    --------
    >>> distribution_of("numpy").startswith("numpy==")
    True
    """
    from importlib import metadata

    top = module.partition(".")[0]
    if top in _DISTRIBUTIONS:
        return _DISTRIBUTIONS[top]
    if top not in _LOOKED_UP:
        try:
            # the import name need not be the distribution's name
            names = metadata.packages_distributions().get(top) or [top]
            dist = metadata.distribution(names[0])
            _LOOKED_UP[top] = f"{dist.metadata['Name']}=={dist.version}"
        except Exception:  # not installed, or broken metadata: never fail a query
            _LOOKED_UP[top] = None
    return _LOOKED_UP[top]


_EDITABLE: dict[str, bool] = {}


def is_editable(module: str) -> bool:
    """True when the code of the distribution providing ``module`` changes without its
    version (:func:`distribution_is_editable`: an editable install, or a source tree
    whose setuptools metadata is found first). False otherwise (and for no distribution).

    Examples
    --------
    >>> is_editable("numpy")
    False
    """
    from importlib import metadata

    dist = distribution_of(module)
    if dist is None:
        return False
    if dist not in _EDITABLE:
        try:
            found = metadata.distribution(dist.partition("==")[0])
        except Exception:  # noqa: BLE001 - missing or broken metadata: not editable
            found = None
        _EDITABLE[dist] = found is not None and distribution_is_editable(found)
    return _EDITABLE[dist]


def distribution_is_editable(found: Any) -> bool:
    """True when the installed distribution ``found`` (an
    :class:`importlib.metadata.Distribution`) changes its code without its version.

    That is an editable install (``pip install -e``: PEP 610 ``direct_url.json`` with
    ``dir_info.editable`` true), or a source tree whose setuptools metadata is found
    first (a ``NAME.egg-info`` folder with ``SOURCES.txt`` and no ``RECORD``, which an
    earlier ``pip install .`` leaves in a project's root: run from there, the module and
    that metadata come from the source tree, not from an install). False otherwise, and
    for missing or unreadable metadata. Used by :func:`is_editable` (encoder
    fingerprints) and by ``quash plugins`` (the plugin's own distribution).

    Examples
    --------
    >>> from importlib import metadata
    >>> distribution_is_editable(metadata.distribution("numpy"))
    False
    """
    import json

    try:
        text = found.read_text("direct_url.json")
        if text:
            return bool(json.loads(text).get("dir_info", {}).get("editable", False))
        # an installer writes RECORD; setuptools' egg_info in a tree SOURCES.txt
        return (
            found.read_text("SOURCES.txt") is not None
            and found.read_text("RECORD") is None
            and found.read_text("installed-files.txt") is None
        )
    except Exception:  # noqa: BLE001 - broken metadata: not editable
        return False
