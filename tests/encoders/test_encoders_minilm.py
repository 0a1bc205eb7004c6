"""The ``minilm`` and ``sentence-transformers`` encoders: real model, fully offline."""

from __future__ import annotations

import contextlib
import os
import socket

import numpy as np
import pytest

from quash_plugins.core import once, registry
from quash_plugins.core.errors import ConfigError, EncoderError

pytest.importorskip("sentence_transformers")


def _cos(a: np.ndarray, b: np.ndarray) -> float:
    return float(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)))


def test_minilm_semantics(minilm):
    emb = minilm.encode_text(["chair", "armchair", "bathtub"])
    assert emb.shape == (3, 384) and emb.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(emb, axis=1), 1.0, atol=1e-5)
    assert _cos(emb[0], emb[1]) > _cos(emb[0], emb[2]) + 0.1


def test_minilm_batches_agree_and_are_deterministic(minilm):
    texts = ["a red sofa", "kitchen sink", "toilet", "chair", "a lamp on the desk"]
    whole = minilm.encode_text(texts)
    one_by_one = np.concatenate([minilm.encode_text([t]) for t in texts])
    np.testing.assert_allclose(whole, one_by_one, atol=1e-5)
    assert minilm.encode_text([]).shape == (0, 384)


def test_minilm_loads_offline_without_network(monkeypatch):
    """A fresh MiniLM loads and encodes with every socket connect refused."""
    from quash_plugins.encoders import _sentence_transformers as st_mod
    from quash_plugins.encoders._sentence_transformers import MiniLMEncoder

    monkeypatch.setattr(st_mod, "_LOADED", {})  # force a real load from disk

    def refuse(*args, **kwargs):
        raise AssertionError(f"network access attempted: {args!r}")

    monkeypatch.setattr(socket.socket, "connect", refuse)
    monkeypatch.setattr(socket, "create_connection", refuse)
    monkeypatch.delenv("HF_HUB_OFFLINE", raising=False)
    monkeypatch.delenv("TRANSFORMERS_OFFLINE", raising=False)
    enc = MiniLMEncoder(device="cpu")
    assert enc.encode_text(["chair"]).shape == (1, 384)
    # The offline switch is set for the load only, then the environment is restored.
    assert "HF_HUB_OFFLINE" not in os.environ
    assert "TRANSFORMERS_OFFLINE" not in os.environ


def test_model_is_loaded_once_per_process(minilm):
    from quash_plugins.encoders._sentence_transformers import MiniLMEncoder

    again = MiniLMEncoder(device="cpu")
    again.encode_text(["x"])
    assert again._model is minilm._model


def test_dim_and_fingerprint_without_loading():
    from quash_plugins.encoders._sentence_transformers import MiniLMEncoder

    enc = MiniLMEncoder(device="cpu")
    assert enc.dim == 384
    fp = enc.fingerprint()
    assert enc._model is None  # neither dim nor fingerprint loaded the model
    assert fp == MiniLMEncoder(device="cpu", batch_size=3).fingerprint()  # batching is not identity
    assert fp != MiniLMEncoder(device="cpu", normalize=False).fingerprint()


def test_registry_creates_minilm_and_rejects_unknown_params():
    enc = registry.create("encoders", "minilm", device="cpu")
    assert enc.name == "minilm" and enc.dim == 384
    with pytest.raises(ConfigError, match="'minilm' does not accept parameter 'nope'"):
        registry.create("encoders", "minilm", nope=1)


def test_sentence_transformers_by_path_matches_minilm(minilm, tmp_path):
    """The generic encoder on a copy of the shipped directory gives the same vectors."""
    import shutil

    from quash_plugins.encoders._sentence_transformers import (
        SentenceTransformerEncoder,
        minilm_model_dir,
    )

    copy = tmp_path / "model"
    shutil.copytree(minilm_model_dir(), copy)
    enc = SentenceTransformerEncoder(model=str(copy), device="cpu")
    assert enc.dim == 384
    texts = ["chair", "bathtub"]
    np.testing.assert_allclose(enc.encode_text(texts), minilm.encode_text(texts), atol=1e-5)
    # Same weights in another place, another identity string: a different fingerprint is
    # conservative and fine; a changed weight file must change it.
    fp = enc.fingerprint()
    (copy / "config.json").write_text((copy / "config.json").read_text() + "\n")
    assert SentenceTransformerEncoder(model=str(copy), device="cpu").fingerprint() != fp


def test_same_weights_share_one_fingerprint(caplog):
    """minilm and sentence-transformers on the same files are one embedding function: one
    fingerprint, so a map built with one is queried with the other without a warning."""
    from quash_plugins.core.types import LatentMap
    from quash_plugins.encoders._sentence_transformers import (
        MiniLMEncoder,
        SentenceTransformerEncoder,
        minilm_model_dir,
    )
    from quash_plugins.engine.map_fit import warn_built_by

    st = SentenceTransformerEncoder(model="sentence-transformers/all-MiniLM-L6-v2", device="cpu")
    if st._path is None or st._path.resolve() != minilm_model_dir().resolve():
        pytest.skip("the id resolves to another copy (a Hugging Face cache) on this machine")
    mini = MiniLMEncoder(device="cpu")
    assert st.fingerprint() == mini.fingerprint()
    assert (
        st.fingerprint()
        != SentenceTransformerEncoder(
            model="sentence-transformers/all-MiniLM-L6-v2", device="cpu", normalize=False
        ).fingerprint()
    )
    lmap = LatentMap(
        embeddings=np.eye(2, 384, dtype=np.float32),
        positions=np.zeros((2, 3), dtype=np.float32),
        source={
            "path": "built.npz",
            "encoder": "minilm",
            "encoder_fingerprint": mini.fingerprint(),
        },
    )
    with caplog.at_level("WARNING"):
        warn_built_by(st, lmap)
    assert "was built with encoder" not in caplog.text
    other = dict(lmap.source, encoder_fingerprint="sentence-transformers-0000000000000000")
    with caplog.at_level("WARNING"):
        warn_built_by(st, LatentMap(lmap.embeddings, positions=lmap.positions, source=other))
    assert "was built with encoder 'minilm'" in caplog.text
    # one name, two embedding functions: said so, not "'minilm' ... but ... is 'minilm'"
    assert "this config's encoder is 'minilm'" not in caplog.text
    assert "this config's 'minilm' is another embedding function" not in caplog.text  # st's name
    assert "this config's encoder is 'sentence-transformers'" in caplog.text
    caplog.clear()
    once.forget("built-by")  # the same map and fingerprints: warned once per process
    with caplog.at_level("WARNING"):
        warn_built_by(mini, LatentMap(lmap.embeddings, positions=lmap.positions, source=other))
    assert f"this config's 'minilm' is another embedding function ({mini.fingerprint()})" in (
        caplog.text
    )


def test_a_map_recorded_under_the_earlier_name_is_not_warned_about(caplog):
    """Maps made before the fingerprint named weights rather than the model string carry
    the earlier name of the same embedding function: no warning for them."""
    from quash_plugins.core.types import LatentMap
    from quash_plugins.encoders._sentence_transformers import MiniLMEncoder
    from quash_plugins.engine.map_fit import warn_built_by

    mini = MiniLMEncoder(device="cpu")
    earlier = mini.earlier_fingerprints()
    assert len(earlier) == 2 and mini.fingerprint() not in earlier
    assert any(e.startswith("minilm-") for e in earlier)
    for i, fp in enumerate(earlier):
        lmap = LatentMap(
            embeddings=np.eye(2, 384, dtype=np.float32),
            source={"path": f"old{i}.npz", "encoder": "minilm", "encoder_fingerprint": fp},
        )
        with caplog.at_level("WARNING"):
            warn_built_by(mini, lmap)
    assert "was built with encoder" not in caplog.text


def test_a_map_built_before_weights_were_named_by_content_is_not_warned_about(caplog):
    """The fingerprint as it was computed before (the weights' resolved path, each weight
    file's size, mtime and safetensors header), computed here from that rule."""
    import hashlib
    import json
    import struct

    from quash_plugins.core.types import LatentMap
    from quash_plugins.encoders._sentence_transformers import MiniLMEncoder
    from quash_plugins.engine.map_fit import warn_built_by

    mini = MiniLMEncoder(device="cpu")
    root = mini._path
    h = hashlib.sha256()
    n = 0
    for p in sorted(q for q in root.rglob("*") if q.is_file()):
        rel = p.relative_to(root).as_posix()
        if p.name in ("config.json", "modules.json", "config_sentence_transformers.json",
                      "sentence_bert_config.json", "tokenizer_config.json",
                      "open_clip_config.json"):  # fmt: skip
            h.update(f"{rel}:".encode() + p.read_bytes())
        elif p.suffix in (".safetensors", ".bin", ".pt", ".pth", ".ckpt", ".msgpack", ".h5"):
            st = p.stat()
            h.update(f"{rel}:{st.st_size}:{st.st_mtime_ns}".encode())
            if p.suffix == ".safetensors":
                with open(p, "rb") as fh:
                    (k,) = struct.unpack("<Q", fh.read(8))
                    h.update(hashlib.sha256(fh.read(k)).hexdigest()[:16].encode())
            n += 1
    weights = {"path": str(root.resolve()), "files": n, "sha": h.hexdigest()[:16]}
    ident = {"family": "sentence-transformers", "normalize": True, "weights": weights}
    old = hashlib.sha256(json.dumps(ident, sort_keys=True).encode()).hexdigest()[:16]
    old = f"sentence-transformers-{old}"
    assert old != mini.fingerprint() and old in mini.earlier_fingerprints()
    lmap = LatentMap(
        embeddings=np.eye(2, 384, dtype=np.float32),
        source={"path": "before.npz", "encoder": "minilm", "encoder_fingerprint": old},
    )
    with caplog.at_level("WARNING"):
        warn_built_by(mini, lmap)
    assert "was built with encoder" not in caplog.text


def test_the_same_weights_in_another_environment_have_one_fingerprint(tmp_path, monkeypatch):
    """A second checkout or a reinstalled venv holds the same files at another path with
    new mtimes: one fingerprint, so its maps and text cache are the same function's."""
    import shutil

    from quash_plugins.encoders._sentence_transformers import (
        MiniLMEncoder,
        SentenceTransformerEncoder,
    )

    monkeypatch.setenv("QUASH_CACHE_DIR", str(tmp_path / "cache"))
    mini = MiniLMEncoder(device="cpu")
    copy = tmp_path / "other-venv" / "model"
    shutil.copytree(mini._path, copy)  # copytree gives the copies new mtimes
    for p in copy.rglob("*.safetensors"):
        os.utime(p, ns=(1, 10**18))
    other = SentenceTransformerEncoder(model=str(copy), device="cpu")
    assert other.fingerprint() == mini.fingerprint()
    # and other weights under the same files' names are another function
    [w] = list(copy.rglob("model.safetensors"))
    data = bytearray(w.read_bytes())
    data[-1] ^= 0xFF
    w.write_bytes(bytes(data))
    assert SentenceTransformerEncoder(model=str(copy), device="cpu").fingerprint() != (
        mini.fingerprint()
    )


def test_sentence_transformers_missing_model_says_how_to_fix():
    from quash_plugins.encoders._sentence_transformers import SentenceTransformerEncoder

    enc = SentenceTransformerEncoder(model="no-such-org/no-such-model", device="cpu")
    with pytest.raises(EncoderError, match="local Hugging Face cache"):
        enc.encode_text(["chair"])


def test_bad_device_is_a_clear_error():
    from quash_plugins.core.errors import ConfigError
    from quash_plugins.encoders._sentence_transformers import MiniLMEncoder

    # refused when the encoder is built, not when a model first loads (a cached query
    # never loads one, so 'device: tpu' used to pass silently)
    with pytest.raises(ConfigError, match="'toaster' is not a supported device"):
        MiniLMEncoder(device="toaster")


def test_auto_device_picks_cpu_without_accelerators(monkeypatch):
    import torch

    from quash_plugins.encoders._runtime import resolve_device

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    monkeypatch.setattr(torch.backends.mps, "is_available", lambda: False)
    assert resolve_device("auto") == "cpu"
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    assert resolve_device("auto") == "cuda"
    assert resolve_device(None) == "cuda"


def test_cuda_requested_without_cuda_fails_clearly(monkeypatch):
    import torch

    from quash_plugins.encoders._runtime import resolve_device

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(EncoderError, match="CUDA is not available"):
        resolve_device("cuda")


def test_long_encode_reports_progress(minilm, monkeypatch):
    from quash_plugins.encoders import _sentence_transformers as mod

    calls = []
    monkeypatch.setattr(mod, "PROGRESS_MIN", 3)
    import quash_plugins.core.progress as prog

    real = prog.progress

    def spy(total, description):
        calls.append(total)
        return real(total, description)

    monkeypatch.setattr(prog, "progress", spy)
    minilm.encode_text(["a", "b", "c", "d"])
    assert calls == [4]


def test_default_model_id_falls_back_to_shipped_copy(minilm):
    from quash_plugins.encoders._sentence_transformers import (
        SentenceTransformerEncoder,
        minilm_model_dir,
    )

    enc = SentenceTransformerEncoder(model="all-MiniLM-L6-v2", device="cpu")
    assert enc._path is not None
    assert enc._path == minilm_model_dir() or (enc._path / "modules.json").exists()
    np.testing.assert_allclose(enc.encode_text(["sofa"]), minilm.encode_text(["sofa"]), atol=1e-5)


def test_an_encode_of_some_hundred_strings_shows_progress_in_steps(minilm, monkeypatch):
    """The adjectives heuristic's ~1,000 phrases ran 12 s with no line: an encode of more
    than PROGRESS_MIN strings is counted, in steps of a few batches, not in one."""
    import quash_plugins.core.progress as prog
    from quash_plugins.encoders import _runtime
    from quash_plugins.encoders import _sentence_transformers as mod

    assert mod.PROGRESS_MIN == _runtime.PROGRESS_MIN < 1000
    totals, steps = [], []
    real = prog.progress

    @contextlib.contextmanager
    def spy(total, description):
        totals.append(total)
        with real(total, description) as advance:
            yield lambda n: (steps.append(n), advance(n))

    monkeypatch.setattr(prog, "progress", spy)
    n = mod.PROGRESS_MIN + 44
    rows = minilm.encode_text([f"thing {i}" for i in range(n)])
    assert rows.shape[0] == n and totals == [n]
    assert sum(steps) == n and len(steps) >= 2, steps
