"""The conformance kit's encoder checks: a faulty encoder fails with the plugin, the
check, what is wrong and the fix; a conformant one passes."""

from __future__ import annotations

from typing import Literal

import numpy as np
import pytest

from quash_plugins import Encoder
from quash_plugins.testing import HashingEncoder, check_encoder

#: The one written list of the encoder checks, in the kit's order: a check dropped from
#: ENCODER_CHECKS fails here and in tests/core/test_third_party_plugin.py, which imports it.
ENCODER_CHECK_NAMES = [
    "check_encoder_output",
    "check_encoder_deterministic",
    "check_encoder_same_in_another_process",
    "check_encoder_batch_independent",
    "check_encoder_empty",
    "check_encoder_empty_string",
    "check_encoder_fingerprint",
    "check_encoder_fingerprint_follows_params",
]


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


class _Words(Encoder):
    """A bag of words; ``empty`` says what it does with a text of no words."""

    name = "words"

    def __init__(self, empty: str = "boundary") -> None:
        self._empty = empty

    @property
    def dim(self) -> int:
        return 8

    def encode_text(self, texts):
        from quash_plugins.core.errors import EncoderError

        if self._empty == "drop":
            texts = [t for t in texts if t]
        if self._empty == "refuse" and "" in texts:
            raise EncoderError("Encoder 'words' cannot embed the empty string")
        rows = np.zeros((len(texts), 8))
        for i, text in enumerate(texts):
            words = text.split() or ([""] if self._empty == "boundary" else [])
            if self._empty == "crash" and not words:
                words = [text.split()[0]]  # IndexError, as a tokenizer's [0] would raise
            for word in words:
                rows[i] += HashingEncoder(8)._word(word)
        norms = np.linalg.norm(rows, axis=1, keepdims=True)
        if self._empty == "zero":
            norms = np.maximum(norms, 1e-12)  # guarded division: a zero row, not NaN
        with np.errstate(invalid="ignore"):
            return (rows / norms).astype(np.float32)

    def config(self):
        return {"empty": self._empty}


@pytest.mark.parametrize(
    ("empty", "says"),
    [
        ("nan", "encode_text(['']) returned NaN/Inf: the empty string has no words"),
        ("zero", "encode_text(['']) returned a row of norm 0: the empty string has no words"),
        ("drop", "encode_text(['']) shape (0, 8), expected (1, 8)"),
        ("crash", "encode_text(['']) raised IndexError"),
    ],
)
def test_the_empty_string_must_be_embedded_or_refused(tmp_path, empty, says):
    """Before, the kit never gave an encoder "", and each of these passed it."""
    from quash_plugins.testing._checks import check_encoder_empty_string

    enc = _Words(empty)
    # the fault shows on "" only: every other text is embedded as it should be
    assert np.allclose(np.linalg.norm(enc.encode_text(["a red chair"]), axis=1), 1.0)
    msg = _failure(enc, tmp_path)
    assert msg.startswith("encoder 'words': check_encoder_empty_string: "), msg
    assert says in msg
    assert "EncoderError" in msg  # the other way out: refuse it
    with pytest.raises(AssertionError):
        check_encoder_empty_string(enc, tmp_path)


@pytest.mark.parametrize("empty", ["boundary", "refuse"])
def test_an_encoder_that_embeds_or_refuses_the_empty_string_passes(tmp_path, empty):
    check_encoder(_Words(empty), tmp_path)


def test_a_refusal_must_say_something(tmp_path):
    class Mute(_Words):
        def encode_text(self, texts):
            if "" in texts:
                raise ValueError()
            return super().encode_text(texts)

    msg = _failure(Mute(), tmp_path)
    assert "check_encoder_empty_string: encode_text(['']) raised ValueError with no message" in msg


class _PrivatePrefix(Encoder):
    """Conformant but for one thing: its prompt ``prefix`` (a string) changes the rows
    and lives in ``_prefix``, which config() does not name."""

    name = "private-prefix"

    def __init__(self, prefix: str = "a photo of") -> None:
        self._prefix = prefix

    @property
    def dim(self) -> int:
        return 8

    def encode_text(self, texts):
        return HashingEncoder(8).encode_text([f"{self._prefix} {t}" for t in texts])

    def config(self):
        return {}


def test_the_kit_catches_a_string_parameter_the_fingerprint_misses(tmp_path):
    """Only numbers and booleans were varied: a prompt prefix that changes every row
    passed, and the text cache served one prefix's embeddings to the other."""
    a, b = _PrivatePrefix(), _PrivatePrefix("a picture of")
    assert a.fingerprint() == b.fingerprint()
    assert not np.allclose(a.encode_text(["chair"]), b.encode_text(["chair"]))
    msg = _failure(_PrivatePrefix(), tmp_path)
    assert msg.startswith("encoder 'private-prefix': check_encoder_fingerprint_follows_params:")
    assert "parameter 'prefix'" in msg and "prefix='a photo of' and prefix='a photo ofx'" in msg

    class Fixed(_PrivatePrefix):
        def config(self):
            return {"prefix": self._prefix}

    check_encoder(Fixed(), tmp_path / "ok")


class _PrivateMode(Encoder):
    """A string parameter with fixed choices, refusing any other value: the kit tries
    the other choices its annotation lists."""

    name = "private-mode"

    def __init__(self, mode: Literal["words", "letters"] | None = "words") -> None:
        if mode not in ("words", "letters"):
            raise ValueError(f"mode must be 'words' or 'letters'; got {mode!r}")
        self._mode = mode

    @property
    def dim(self) -> int:
        return 8

    def encode_text(self, texts):
        split = (lambda t: " ".join(t)) if self._mode == "letters" else (lambda t: t)
        return HashingEncoder(8).encode_text([split(t) for t in texts])

    def config(self):
        return {}


def test_a_string_with_fixed_choices_is_varied_over_them(tmp_path):
    msg = _failure(_PrivateMode(), tmp_path)
    assert msg.startswith("encoder 'private-mode': check_encoder_fingerprint_follows_params:")
    assert "mode='words' and mode='letters'" in msg

    class Fixed(_PrivateMode):
        def config(self):
            return {"mode": self._mode}

    check_encoder(Fixed(), tmp_path / "ok")


def test_a_string_parameter_that_does_not_change_the_output_passes(tmp_path):
    class Labelled(_PrivatePrefix):
        def encode_text(self, texts):  # the prefix is a label only
            return HashingEncoder(8).encode_text(list(texts))

    check_encoder(Labelled(), tmp_path)


def test_the_encoder_checks_have_a_module_of_their_own_and_are_importable_as_before():
    """They moved out of _checks.py (864 lines); the names a plugin's tests imported from
    there are the same functions, and the kit runs them in the same order."""
    from quash_plugins.testing import _checks, _encoder_checks

    names = [c.__name__ for c in _encoder_checks.ENCODER_CHECKS]
    assert names == ENCODER_CHECK_NAMES
    for name in names:
        assert getattr(_checks, name) is getattr(_encoder_checks, name)
        assert getattr(_encoder_checks, name).__module__ == _encoder_checks.__name__
    assert _checks._CHECKS["encoders"] == _encoder_checks.ENCODER_CHECKS


class _Remote(Encoder):
    """An encoder that 'sends' its key and writes a log file: the kit must vary
    neither, since a changed key goes to a server and a changed path is a new file."""

    name = "remote"
    keys_sent: list[str] = []

    def __init__(self, api_key: str = "sk-test-0123456789", log: str = "remote.log") -> None:
        self._api_key = api_key
        self._log = log

    @property
    def dim(self) -> int:
        return 8

    def encode_text(self, texts):
        type(self).keys_sent.append(self._api_key)
        with open(self._log, "a", encoding="utf-8") as f:
            f.write(f"{len(texts)}\n")
        return HashingEncoder(8).encode_text(list(texts))

    def config(self):
        return {}


def test_a_key_or_a_path_is_not_varied(tmp_path):
    log = tmp_path / "remote.log"
    _Remote.keys_sent = []
    check_encoder(_Remote(log=str(log)), tmp_path / "kit")
    assert log.is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["kit", "remote.log"]
    assert set(_Remote.keys_sent) == {"sk-test-0123456789"}


def test_a_key_in_a_dict_is_not_varied_whatever_its_type():
    """A number under a credential's name (``api_key=12345``) was nudged: the numbers
    were tried before the name."""
    from quash_plugins.testing._encoder_checks import _nudged

    assert _nudged("api_key", 12345) == [] and _nudged("token", 7.5) == []
    assert _nudged("options", {"api_key": 12345, "token": 7.5}) == []
    assert _nudged("options", {"api_key": 12345, "scale": 2}) == [{"api_key": 12345, "scale": 3}]


@pytest.mark.parametrize(
    "old",
    [
        ["/models/a.pt", "/models/b.pt"],
        ("/models/a.pt",),
        ["https://example.com/a.pt", "b"],
        [["/models/a.pt"], ["/models/b.pt"]],
        [{"file": "/models/a.pt"}, {"file": "/models/b.pt"}],
    ],
)
def test_a_list_of_paths_or_urls_is_not_varied(old):
    """A list of weight files was shortened (``[['/models/a.pt']]``): one file fewer is
    only a model that does not load, or a file written beside the one named."""
    from quash_plugins.testing._encoder_checks import _nudged

    assert _nudged("weights_files", old) == []
    assert _nudged("options", {"files": old}) == []


def test_lists_and_dicts_of_plain_values_are_still_varied():
    from quash_plugins.testing._encoder_checks import _nudged

    assert _nudged("sizes", [1, 2]) == [[1], [1, 3]]
    assert _nudged("words", ("a", "b")) == [("a",), ("a", "bx")]
    assert _nudged("opts", {"files": ["/a.pt"], "n": 1}) == [{"files": ["/a.pt"], "n": 2}]


class _VocabFile(Encoder):
    """Needs a file (no default), keeps it as ``_words`` (not ``vocab``), and keeps its
    ``seed`` out of config(): two seeds share a fingerprint."""

    name = "vocab-file"

    def __init__(self, vocab: str, seed: int = 0) -> None:
        with open(vocab, encoding="utf-8") as f:
            self._words = f.read().split()
        self._seed = seed

    @classmethod
    def conformance_params(cls, tmp_path):
        path = tmp_path / "vocab.txt"
        path.write_text("chair table sofa\n", encoding="utf-8")
        return {"vocab": str(path)}

    @property
    def dim(self) -> int:
        return 8

    def encode_text(self, texts):
        return HashingEncoder(8).encode_text([f"{self._seed} {t}" for t in texts])

    def config(self):
        return {"words": self._words}


def test_a_required_parameter_under_another_name_does_not_skip_the_fingerprint_check(
    tmp_path,
):
    """The kit guessed the constructor's parameters from the instance's attributes only;
    'vocab', kept as '_words', was unknown, so the fingerprint check returned early and
    the seed the fingerprint misses passed. The kit now knows what it built it with."""
    from quash_plugins.core import registry
    from quash_plugins.testing import check_plugin

    assert _VocabFile(**_VocabFile.conformance_params(tmp_path)).fingerprint() == (
        _VocabFile(seed=1, **_VocabFile.conformance_params(tmp_path)).fingerprint()
    )
    registry.register("encoders", "kit-vocab-file", _VocabFile, dist="lab-vocab")
    try:
        with pytest.raises(AssertionError) as err:
            check_plugin("encoders", "kit-vocab-file", tmp_path / "kit")
    finally:
        registry.unregister("encoders", "kit-vocab-file", dist="lab-vocab")
    msg = str(err.value)
    assert msg.startswith("encoders:kit-vocab-file-check_encoder_fingerprint_follows_params: ")
    assert "parameter 'seed'" in msg and "seed=0 and seed=1" in msg


class _PrivateTemplates(Encoder):
    """Prompt templates (a list) and their weights (a dict), kept private: a config()
    that names neither leaves both out of the fingerprint."""

    name = "private-templates"

    def __init__(
        self, templates: list[str] | None = None, weights: dict[str, float] | None = None
    ) -> None:
        self._templates = list(templates or ["a photo of {}", "a {} in a room"])
        self._weights = dict(weights or {"photo": 1.0, "room": 0.25})

    @property
    def dim(self) -> int:
        return 8

    def encode_text(self, texts):
        rows = np.zeros((len(texts), 8), dtype=np.float32)
        for template in self._templates:
            weight = sum(w for word, w in self._weights.items() if word in template) or 1.0
            rows += weight * HashingEncoder(8).encode_text([template.format(t) for t in texts])
        return rows / np.linalg.norm(rows, axis=1, keepdims=True)

    def config(self):
        return {"templates": self._templates, "weights": self._weights}


def test_the_kit_catches_a_list_parameter_the_fingerprint_misses(tmp_path):
    """Only numbers, booleans and strings were varied: a list of prompt templates that
    changes every row passed, and the text cache served one list's embeddings to the
    other."""

    class NoTemplates(_PrivateTemplates):
        def config(self):
            return {"weights": self._weights}

    a, b = NoTemplates(), NoTemplates(["a photo of {}"])
    assert a.fingerprint() == b.fingerprint()
    assert not np.allclose(a.encode_text(["chair"]), b.encode_text(["chair"]))
    msg = _failure(NoTemplates(), tmp_path)
    assert msg.startswith("encoder 'private-templates': check_encoder_fingerprint_follows_params:")
    assert "parameter 'templates'" in msg
    assert "templates=['a photo of {}', 'a {} in a room'] and templates=['a photo of {}']" in msg


def test_the_kit_catches_a_dict_parameter_the_fingerprint_misses(tmp_path):
    class NoWeights(_PrivateTemplates):
        def config(self):
            return {"templates": self._templates}

    msg = _failure(NoWeights(), tmp_path)
    assert "parameter 'weights'" in msg
    assert "weights={'photo': 1.0, 'room': 0.25} and weights={'photo': 2.0, 'room': 0.25}" in msg


def test_list_and_dict_parameters_the_fingerprint_follows_pass(tmp_path):
    check_encoder(_PrivateTemplates(), tmp_path / "config")

    class Public(_PrivateTemplates):
        """The default config(): public list and dict attributes are plain data."""

        def __init__(self, templates=None, weights=None):
            super().__init__(templates, weights)
            self.templates, self.weights = self._templates, self._weights

        config = Encoder.config

    assert set(Public().config()) == {"templates", "weights"}
    check_encoder(Public(), tmp_path / "default")


class _RemoteOptions(_Remote):
    """A dict of request options with a credential inside, and a list of log files:
    the kit varies neither the key nor a path (a shorter list only writes less)."""

    name = "remote-options"

    def __init__(self, options: dict | None = None, logs: list[str] | None = None) -> None:
        self.options = dict(options or {"api_key": "sk-test-0123456789", "retries": 2})
        self.logs = list(logs or ["remote.log"])
        super().__init__(self.options["api_key"], self.logs[0])


def test_a_key_or_a_path_inside_a_list_or_dict_is_not_varied(tmp_path):
    log = tmp_path / "remote.log"
    _Remote.keys_sent = []
    check_encoder(_RemoteOptions(logs=[str(log)]), tmp_path / "kit")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["kit", "remote.log"]
    assert set(_Remote.keys_sent) == {"sk-test-0123456789"}
