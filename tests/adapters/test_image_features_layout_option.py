"""A ``layout`` option the frames do not have is refused naming the field, the option
and the layout that reads them; it said only "expected (1, D, h, w); got shape ..."."""

from __future__ import annotations

import numpy as np
import pytest
from _cf_writers import save_feat_pt

from quash_plugins.core import registry
from quash_plugins.core.errors import MapFormatError


def test_a_layout_option_the_frames_lack_names_the_option_and_the_one_that_reads_them(
    tmp_path,
):
    hwd = tmp_path / "saved-feat"
    save_feat_pt(hwd, "frame0", np.ones((4, 5, 8), np.float16))  # ConceptFusion's (H, W, D)
    lseg = tmp_path / "lseg-feat"
    lseg.mkdir()
    np.save(lseg / "frame0.npy", np.ones((1, 8, 4, 5), np.float32))  # LSeg's (1, D, h, w)
    adapter = registry.create("adapters", "image-features")

    for folder, given, fits in ((hwd, "1dhw", "hwd"), (lseg, "hwd", "1dhw")):
        with pytest.raises(MapFormatError) as refused:
            adapter.read(folder, layout=given)
        said = str(refused.value)
        assert "frame0" in said and "field 'embeddings'" in said
        assert f"option layout={given}" in said and f"layout={fits}" in said
        # the layout the error names reads the frame: 4 x 5 pixels of 8 dimensions
        assert adapter.read(folder, layout=fits).embeddings.shape == (20, 8)
        assert adapter.read(folder).embeddings.shape == (20, 8)  # auto, as it says
