"""The conformance kit's encoder checks: a faulty encoder fails with the plugin, the
check, what is wrong and the fix; a conformant one passes."""

from __future__ import annotations

import numpy as np
import pytest

from quash_plugins import Encoder
from quash_plugins.testing import HashingEncoder, check_encoder


class _Faulty(Encoder):
    """HashingEncoder's rows with one fault chosen by ``fault``."""

    name = "faulty"

    def __init__(self, fault: str = "none", dim: int = 8) -> None:
        self._fault = fault
        self._dim = dim

    @property
    def dim(self) -> int:
        return self._dim

    def encode_text(self, texts):
        rows = HashingEncoder(self._dim).encode_text(texts)
        if self._fault == "scaled":
            return rows * np.arange(2, len(rows) + 2, dtype=np.float32)[:, None]
        if self._fault == "float64":
            return rows.astype(np.float64)
        if self._fault == "nan-for-sink":
            rows[[t == "kitchen sink" for t in texts]] = np.nan
        return rows

    def config(self):
        return {"dim": self._dim, "fault": self._fault}


def _failure(enc, tmp_path) -> str:
    with pytest.raises(AssertionError) as err:
        check_encoder(enc, tmp_path)
    return str(err.value)


def test_rows_off_unit_norm_name_the_text_the_norm_and_the_fix(tmp_path):
    msg = _failure(_Faulty("scaled"), tmp_path)
    assert msg.startswith("encoder 'faulty': check_encoder_output: rows must be L2-normalised")
    # "chair" x2, "a red chair" x3, "kitchen sink" x4: the worst row is named
    assert "3 of 3 rows" in msg and "'kitchen sink' has norm 4" in msg
    assert "np.linalg.norm(rows, axis=1, keepdims=True)" in msg


def test_float64_names_the_dtype_and_the_fix(tmp_path):
    msg = _failure(_Faulty("float64"), tmp_path)
    assert msg.startswith("encoder 'faulty': check_encoder_output: encode_text dtype float64")
    assert "rows.astype(np.float32)" in msg


def test_nan_rows_name_the_text(tmp_path):
    msg = _failure(_Faulty("nan-for-sink"), tmp_path)
    assert msg.startswith("encoder 'faulty': check_encoder_output: encode_text returned NaN")
    assert "for 'kitchen sink'" in msg


def test_a_conformant_encoder_passes(tmp_path):
    check_encoder(_Faulty("none"), tmp_path)
