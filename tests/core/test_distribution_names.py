"""A plugin's distribution is found whatever its import name: ``acme-vision-encoders``
installs the package ``acme_qp_dist``, and registers ``acme_qp_dist:AcmeText`` (an entry
point with no dot). Its encoder fingerprint then holds the distribution's version, so a
new release never serves the embeddings cached by the one before, even when only the
package's data (not its code) changed. The distribution is a real ``importlib.metadata``
one, laid out in a folder on ``sys.path`` as an installer leaves it.
"""

from __future__ import annotations

import importlib
import shutil
import sys

import pytest

from quash_plugins.core import _distributions, registry

_MODULE = """
import numpy as np
from quash_plugins import Encoder


class AcmeText(Encoder):
    name = "acme-text"

    @property
    def dim(self):
        return 4

    def encode_text(self, texts):
        return np.tile(np.float32([1, 0, 0, 0]), (len(texts), 1))
"""
DIST, MODULE = "acme-vision-encoders", "acme_qp_dist"


def _install(root, version):
    """Lay out the distribution at ``version`` (a release: RECORD, no direct_url.json)."""
    for old in root.glob("*.dist-info"):
        shutil.rmtree(old)
    package = root / MODULE
    package.mkdir(exist_ok=True)
    (package / "__init__.py").write_text(_MODULE, encoding="utf-8")
    info = root / f"acme_vision_encoders-{version}.dist-info"
    info.mkdir()
    meta = f"Metadata-Version: 2.1\nName: {DIST}\nVersion: {version}\n"
    (info / "METADATA").write_text(meta, encoding="utf-8")
    (info / "RECORD").write_text(f"{MODULE}/__init__.py,,\n{info.name}/METADATA,,\n")
    (info / "entry_points.txt").write_text(
        f"[quash_plugins.encoders]\nacme-text = {MODULE}:AcmeText\n", encoding="utf-8"
    )


def _forget():
    sys.modules.pop(MODULE, None)
    _distributions._DISTRIBUTIONS.pop(MODULE, None)
    _distributions._LOOKED_UP.pop(MODULE, None)
    _distributions._EDITABLE.clear()
    importlib.invalidate_caches()
    registry.refresh()


@pytest.fixture
def site(tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(tmp_path))
    _forget()
    yield tmp_path
    monkeypatch.undo()
    _forget()


def test_the_scanned_entry_point_names_the_distribution(site):
    _install(site, "1.0.0")
    enc = registry.create("encoders", "acme-text")
    assert registry.distribution_of(MODULE) == f"{DIST}==1.0.0"
    assert registry.distribution_of(f"{MODULE}.sub") == f"{DIST}==1.0.0"
    assert not registry.is_editable(MODULE)  # a release: its version names its code
    first = enc.fingerprint()
    # a new release: the fingerprint follows the version, and the code is not hashed
    _forget()
    _install(site, "5.0.0")
    enc = registry.create("encoders", "acme-text")
    assert registry.distribution_of(MODULE) == f"{DIST}==5.0.0"
    assert enc.fingerprint() != first


def test_an_unscanned_module_is_found_by_the_files_its_distribution_installed(site):
    _install(site, "2.1.0")
    # no entry point scanned: looked up through the distributions' file lists
    assert registry.distribution_of(MODULE) == f"{DIST}==2.1.0"


def test_note_distribution_takes_an_entry_point_value():
    try:
        registry.note_distribution("acme_qp_note:Thing", "acme-note", "0.1")
        registry.note_distribution("acme_qp_note2.sub.mod:Thing", "acme-note2", "0.2")
        assert registry.distribution_of("acme_qp_note") == "acme-note==0.1"
        assert registry.distribution_of("acme_qp_note2.other") == "acme-note2==0.2"
    finally:
        for top in ("acme_qp_note", "acme_qp_note2"):
            _distributions._DISTRIBUTIONS.pop(top, None)
