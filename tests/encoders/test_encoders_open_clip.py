"""The ``open-clip`` encoder, with random weights and local checkpoints (no network)."""

from __future__ import annotations

import json
import socket

import numpy as np
import pytest

from quash_plugins.core.errors import ConfigError, EncoderError

open_clip = pytest.importorskip("open_clip")
torch = pytest.importorskip("torch")

TINY = "quash-tiny-clip-test"
TINY_CFG = {
    "embed_dim": 24,
    "vision_cfg": {"image_size": 32, "layers": 1, "width": 32, "head_width": 16, "patch_size": 16},
    "text_cfg": {"context_length": 16, "vocab_size": 49408, "width": 32, "heads": 2, "layers": 1},
}


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """Register a tiny CLIP architecture with open_clip (its own config mechanism)."""
    d = tmp_path_factory.mktemp("oc-configs")
    (d / f"{TINY}.json").write_text(json.dumps(TINY_CFG))
    open_clip.add_model_config(d)
    return TINY


@pytest.fixture
def no_network(monkeypatch):
    def refuse(*args, **kwargs):
        raise AssertionError(f"network access attempted: {args!r}")

    monkeypatch.setattr(socket.socket, "connect", refuse)
    monkeypatch.setattr(socket, "create_connection", refuse)


def _enc(**kw):
    from quash_plugins.encoders._open_clip import OpenClipEncoder

    kw.setdefault("device", "cpu")
    return OpenClipEncoder(**kw)


def _fresh(**kw):
    """An encoder that really builds its model (not the per-process loaded copy)."""
    from quash_plugins.encoders import _open_clip

    _open_clip._LOADED.clear()
    return _enc(**kw)


def test_random_weights_text_embeddings(tiny, no_network):
    enc = _enc(model=tiny, pretrained="random")
    assert enc.dim == 24
    emb = enc.encode_text(["chair", "sofa", "chair"])
    assert emb.shape == (3, 24) and emb.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(emb, axis=1), 1.0, atol=1e-5)
    np.testing.assert_allclose(emb[0], emb[2], atol=1e-6)
    assert not np.allclose(emb[0], emb[1])
    assert enc.encode_text([]).shape == (0, 24)


def test_matches_open_clip_directly(tiny):
    """Our path equals open_clip's own encode_text + L2 normalisation on the same model."""
    enc = _fresh(model=tiny, pretrained="random", batch_size=2)
    model, tokenizer, _ = enc._load()
    texts = ["a chair", "a red sofa", "bathtub"]
    with torch.no_grad():
        ref = model.encode_text(tokenizer(texts)).float()
    ref = (ref / ref.norm(dim=-1, keepdim=True)).numpy()
    np.testing.assert_allclose(enc.encode_text(texts), ref, atol=1e-5)


def test_random_init_is_seeded(tiny):
    a = _fresh(model=tiny, pretrained="random", seed=0).encode_text(["chair"])
    b = _fresh(model=tiny, pretrained="random", seed=0).encode_text(["chair"])
    c = _fresh(model=tiny, pretrained="random", seed=1).encode_text(["chair"])
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)
    assert (
        _enc(model=tiny, pretrained="random", seed=0).fingerprint()
        != _enc(model=tiny, pretrained="random", seed=1).fingerprint()
    )


@pytest.mark.parametrize("how", ["checkpoint", "pretrained"])
def test_checkpoint_by_path_gives_identical_embeddings(tiny, tmp_path, no_network, how):
    src = _fresh(model=tiny, pretrained="random", seed=3)
    model = src._load()[0]
    path = tmp_path / "tiny.pt"
    torch.save(model.state_dict(), path)
    texts = ["chair", "armchair", "bathtub"]
    ref = src.encode_text(texts)
    loaded = _fresh(model=tiny, seed=99, **{how: str(path)})  # another seed: weights from file
    np.testing.assert_array_equal(loaded.encode_text(texts), ref)
    fp = loaded.fingerprint()
    assert fp != src.fingerprint()
    torch.save({k: v + 0.01 for k, v in model.state_dict().items()}, path)
    assert _enc(model=tiny, checkpoint=str(path)).fingerprint() != fp  # new weights, new key


def test_local_dir_and_hf_cache_schemas(tiny, tmp_path, no_network):
    from safetensors.torch import save_file

    src = _fresh(model=tiny, pretrained="random", seed=5)
    state = {k: v.contiguous() for k, v in src._load()[0].state_dict().items()}
    ref = src.encode_text(["chair"])
    cfg = json.dumps({"model_cfg": TINY_CFG, "preprocess_cfg": {}})
    # local-dir: a folder with open_clip_config.json + open_clip_model.safetensors
    d = tmp_path / "folder"
    d.mkdir()
    (d / "open_clip_config.json").write_text(cfg)
    save_file(state, str(d / "open_clip_model.safetensors"))
    enc = _fresh(model=f"local-dir:{d}")
    assert enc.dim == 24
    np.testing.assert_allclose(enc.encode_text(["chair"]), ref, atol=1e-6)
    # hf-hub: the same files laid out as a Hugging Face cache entry, read offline
    cache = tmp_path / "hub"
    snap = cache / "models--org--tiny" / "snapshots" / "abc123"
    snap.mkdir(parents=True)
    (cache / "models--org--tiny" / "refs").mkdir()
    (cache / "models--org--tiny" / "refs" / "main").write_text("abc123")
    (snap / "open_clip_config.json").write_text(cfg)
    save_file(state, str(snap / "open_clip_model.safetensors"))
    enc = _fresh(model="hf-hub:org/tiny", cache_dir=str(cache))
    assert enc.dim == 24
    np.testing.assert_allclose(enc.encode_text(["chair"]), ref, atol=1e-6)


def test_missing_hf_hub_model_names_files(tmp_path, no_network):
    with pytest.raises(EncoderError) as err:
        _enc(model="hf-hub:org/not-here", cache_dir=str(tmp_path))
    msg = str(err.value)
    assert "open_clip_config.json" in msg and "open_clip_model.safetensors" in msg
    assert "org/not-here" in msg


@pytest.mark.parametrize("preset", ["lseg", "openseg", "conceptfusion"])
def test_missing_preset_weights_fail_fast_with_file_and_place(preset, tmp_path, no_network):
    from quash_plugins.encoders._open_clip import OPEN_CLIP_PRESETS

    model, tag = OPEN_CLIP_PRESETS[preset][:2]
    cfg = open_clip.get_pretrained_cfg(model, tag)
    with pytest.raises(EncoderError) as err:
        _enc(preset=preset, cache_dir=str(tmp_path))
    msg = str(err.value)
    assert model in msg and "checkpoint" in msg and "offline" in msg
    repo = cfg["hf_hub"].rstrip("/")
    assert repo in msg and "open_clip_model.safetensors" in msg
    if cfg.get("url"):
        assert str(tmp_path / cfg["url"].rsplit("/", 1)[-1]) in msg


def test_presets_match_open_clip_and_pipeline():
    """Preset towers exist in open_clip with the stated tag and dimension."""
    from quash_plugins.encoders._open_clip import OPEN_CLIP_PRESETS
    from quash_plugins.engine.map_fit import PRESETS_BY_DIM

    for preset, (model, tag, dim, _) in OPEN_CLIP_PRESETS.items():
        assert model in open_clip.list_models()
        assert tag in open_clip.list_pretrained_tags_by_model(model)
        assert open_clip.get_model_config(model)["embed_dim"] == dim
        assert f"'{preset}'" in PRESETS_BY_DIM[dim]
        assert _enc(preset=preset, pretrained="random").dim == dim  # no weights needed


def test_tag_weights_found_in_url_cache_are_used(tiny, tmp_path, monkeypatch, no_network):
    """A tag whose file sits where open_clip caches URL downloads loads offline."""
    from quash_plugins.encoders import _open_clip_weights as w

    src = _fresh(model=tiny, pretrained="random", seed=7)
    torch.save(src._load()[0].state_dict(), tmp_path / "tiny-weights.pt")
    fake = {"url": "https://example.invalid/x/tiny-weights.pt", "hf_hub": "", "quick_gelu": False}
    monkeypatch.setattr(
        open_clip, "get_pretrained_cfg", lambda m, t: fake if t == "faketag" else {}
    )
    monkeypatch.setattr(w, "hf_cached_file", lambda *a, **k: None)
    enc = _fresh(model=tiny, pretrained="faketag", cache_dir=str(tmp_path))
    np.testing.assert_array_equal(enc.encode_text(["chair"]), src.encode_text(["chair"]))


def test_bad_parameters_are_config_errors(tiny):
    with pytest.raises(ConfigError, match="preset"):
        _enc(preset="lsegg")
    with pytest.raises(ConfigError, match="ViT-B-32"):
        _enc(model="ViT-B-33")
    with pytest.raises(ConfigError, match="neither a tag"):
        _enc(model="ViT-B-32", pretrained="opnai")
    with pytest.raises(EncoderError, match="does not exist"):
        _enc(model=tiny, checkpoint="/no/such/file.pt")
    with pytest.raises(ConfigError, match="precision"):
        _enc(model=tiny, precision="fp8")
    with pytest.raises(ConfigError, match="model"):
        _enc()


def test_precision_and_device_resolution(tiny, monkeypatch):
    enc = _enc(model=tiny, pretrained="random", device="auto")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    monkeypatch.setattr(torch.backends.mps, "is_available", lambda: False)
    assert enc.device == "cpu" and enc.resolved_precision == "fp32"
    gpu = _enc(model=tiny, pretrained="random", device="auto")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    assert gpu.device == "cuda" and gpu.resolved_precision == "fp16"
    assert gpu.fingerprint() != enc.fingerprint()  # half precision is another function


def test_encode_images(tiny, tmp_path):
    from PIL import Image

    enc = _enc(model=tiny, pretrained="random")
    rng = np.random.default_rng(0)
    a = rng.integers(0, 255, size=(40, 50, 3), dtype=np.uint8)
    b = rng.integers(0, 255, size=(32, 32, 3), dtype=np.uint8)
    Image.fromarray(b).save(tmp_path / "b.png")
    emb = enc.encode_images([a, str(tmp_path / "b.png")])
    assert emb.shape == (2, 24) and emb.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(emb, axis=1), 1.0, atol=1e-5)
    np.testing.assert_allclose(enc.encode_images([b])[0], emb[1], atol=1e-5)


def test_through_config_and_pipeline(tiny):
    from quash_plugins import Quash
    from quash_plugins.core.types import LatentMap

    q = Quash.from_config(
        {
            "encoder": {"name": "open-clip", "model": tiny, "pretrained": "random"},
            "classifier": "contrast",
            "device": "cpu",
            "cache": False,
            "instances": False,
        }
    )
    assert q.encoder.device == "cpu"
    W = q.encoder.encode_text(["chair", "other"])
    lmap = LatentMap(np.repeat(W, 5, axis=0))
    res = q.query(lmap, "chair")
    assert res.mask[:5].all() and not res.mask[5:].any()


@pytest.mark.slow
def test_vit_b32_random_weights_real_architecture():
    enc = _enc(preset="lseg", pretrained="random")
    assert enc.encode_text(["chair"]).shape == (1, 512)


def test_tag_preprocessing_applies_to_a_checkpoint(tiny, tmp_path, monkeypatch, no_network):
    """A tag with preprocessing settings (every preset's: OpenAI's mean, std, bicubic,
    shortest) loads a checkpoint, and its image preprocessing uses them: open_clip's
    create_model_and_transforms refused them as force_preprocess_cfg ('got multiple
    values'), so preset: lseg failed to load any weights."""
    src = _fresh(model=tiny, pretrained="random", seed=7)
    torch.save(src._load()[0].state_dict(), tmp_path / "tiny.pt")
    fake = {
        "url": "https://example.invalid/x/tiny.pt",
        "hf_hub": "",
        "mean": (0.25, 0.5, 0.75),
        "std": (0.1, 0.2, 0.3),
        "interpolation": "bicubic",
        "resize_mode": "shortest",
    }
    monkeypatch.setattr(
        open_clip, "get_pretrained_cfg", lambda m, t: fake if t == "faketag" else {}
    )
    for kw in (
        {"pretrained": "faketag", "cache_dir": str(tmp_path)},
        {"pretrained": "faketag", "checkpoint": str(tmp_path / "tiny.pt")},
    ):
        enc = _fresh(model=tiny, **kw)
        np.testing.assert_array_equal(enc.encode_text(["chair"]), src.encode_text(["chair"]))
        norm = [t for t in enc._load()[2].transforms if type(t).__name__ == "Normalize"][0]
        assert tuple(norm.mean) == fake["mean"] and tuple(norm.std) == fake["std"]


def test_local_dir_without_weights_is_refused(tiny, tmp_path, no_network):
    """A local-dir folder with open_clip_config.json but no weight file was loaded with
    random (unseeded) weights and cached as if they were the folder's."""
    (tmp_path / "open_clip_config.json").write_text(
        json.dumps({"model_cfg": TINY_CFG, "preprocess_cfg": {}})
    )
    with pytest.raises(EncoderError) as err:
        _fresh(model=f"local-dir:{tmp_path}")
    assert str(tmp_path) in str(err.value) and "open_clip_model.safetensors" in str(err.value)


def test_open_clip_root_warnings_go_through_the_package_logger(tiny, tmp_path):
    """open_clip logs on the root logger: with pretrained: random it printed its own
    unformatted 'WARNING:root:No pretrained weights loaded ...' past --quiet, and left
    Python's default handler on the root logger for every later record."""
    import subprocess
    import sys

    (tmp_path / f"{TINY}.json").write_text(json.dumps(TINY_CFG))
    code = (
        "import logging, open_clip\n"
        f"open_clip.add_model_config({str(tmp_path)!r})\n"
        "from quash_plugins.encoders._open_clip import OpenClipEncoder\n"
        f"OpenClipEncoder(model={TINY!r}, pretrained='random', device='cpu')"
        ".encode_text(['chair'])\n"
        "print(logging.getLogger().handlers)\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "WARNING:root" not in done.stderr and "No pretrained" not in done.stderr
    assert done.stdout.strip() == "[]"


def test_open_clip_warnings_are_relogged_unless_random_was_asked_for(tmp_path, caplog):
    import logging

    from quash_plugins.encoders._open_clip_weights import open_clip_logs

    (tmp_path / "open_clip_config.json").write_text(json.dumps({"model_cfg": TINY_CFG}))
    log = logging.getLogger("quash_plugins.encoders._open_clip")
    for random in (False, True):
        caplog.clear()
        with caplog.at_level(logging.WARNING), open_clip_logs(log, random):
            open_clip.create_model(f"local-dir:{tmp_path}")
        assert not [r for r in caplog.records if r.name == "root"]
        got = [r.getMessage() for r in caplog.records if r.name == log.name]
        assert any("no CLIP weights found" in m for m in got)
        assert any("No pretrained weights" in m for m in got) is not random


def test_checkpoint_of_another_architecture_names_the_file_and_field(tiny, tmp_path):
    """A checkpoint that is not this architecture's said only 'text pos_embed width
    changed!' or listed every missing key (kilobytes), an empty state dict said nothing
    at all (''); now the reason is one short line and the fix names 'model'."""
    wide = {**TINY_CFG, "text_cfg": {**TINY_CFG["text_cfg"], "width": 64, "heads": 4}}
    (tmp_path / "quash-tiny-wide-test.json").write_text(json.dumps(wide))
    open_clip.add_model_config(tmp_path)
    torch.save(
        _fresh(model=tiny, pretrained="random")._load()[0].state_dict(), tmp_path / "tiny.pt"
    )
    torch.save({"state_dict": {}}, tmp_path / "empty.pt")
    torch.save({"epoch": 3, "optimizer": {"lr": torch.zeros(1)}}, tmp_path / "other.pt")
    cases = [("quash-tiny-wide-test", "tiny.pt"), (tiny, "empty.pt"), (tiny, "other.pt")]
    for model, name in cases:
        with pytest.raises(EncoderError) as err:
            _fresh(model=model, checkpoint=str(tmp_path / name)).encode_text(["chair"])
        msg = str(err.value)
        assert name in msg and "'model'" in msg and len(msg) < 1000, msg
        assert not msg.rstrip().endswith(":"), msg  # a reason is given
    with pytest.raises(EncoderError, match="is a folder"):
        _enc(model=tiny, checkpoint=str(tmp_path))


def test_hf_hub_and_local_dir_models_refuse_checkpoint_and_pretrained(tmp_path, no_network):
    """An hf-hub: or local-dir: model loads its own weights: a 'checkpoint' or 'pretrained'
    beside it was ignored without a word, and the missing-weights error of an hf-hub:
    model advised exactly that ('pass any local hf-hub:... state-dict file as
    checkpoint')."""
    for model in ("hf-hub:org/tiny", f"local-dir:{tmp_path}"):
        for extra in ({"checkpoint": str(tmp_path / "w.pt")}, {"pretrained": "openai"}):
            with pytest.raises(ConfigError, match=f"'{next(iter(extra))}'"):
                _enc(model=model, **extra)
    with pytest.raises(EncoderError) as err:
        _enc(model="hf-hub:org/not-here", cache_dir=str(tmp_path))
    assert "checkpoint:" not in str(err.value)


def test_hf_hub_revision_with_another_config_is_another_fingerprint(tiny, tmp_path, no_network):
    """A new revision of an hf-hub: repository whose open_clip_config.json changed (here
    QuickGELU) and whose weight file did not gives other embeddings; its fingerprint was
    the weight file's alone, so the text cache served the old revision's rows."""
    from safetensors.torch import save_file

    state = {k: v.contiguous() for k, v in open_clip.create_model(tiny).state_dict().items()}
    cache = tmp_path / "hub"
    repo = cache / "models--org--tiny"
    (repo / "refs").mkdir(parents=True)
    encoders = []
    for rev, quick in (("aaa111", False), ("bbb222", True)):
        snap = repo / "snapshots" / rev
        snap.mkdir(parents=True)
        cfg = {"model_cfg": {**TINY_CFG, "quick_gelu": quick}, "preprocess_cfg": {}}
        (snap / "open_clip_config.json").write_text(json.dumps(cfg))
        save_file(state, str(snap / "open_clip_model.safetensors"))
        (repo / "refs" / "main").write_text(rev)
        enc = _fresh(model="hf-hub:org/tiny", cache_dir=str(cache))
        encoders.append((enc, enc.encode_text(["chair"])))
    (old, old_rows), (new, new_rows) = encoders
    assert not np.array_equal(old_rows, new_rows)
    assert old.fingerprint() != new.fingerprint()
    # a map recorded before the config was named is still the same encoder's
    from quash_plugins.encoders._runtime import weights_identity

    assert new._fingerprint(weights_identity(new._resolved.weights)) in (new.earlier_fingerprints())


def test_openai_torchscript_file_loads(tiny, tmp_path, monkeypatch, no_network):
    """OpenAI's own checkpoints (~/.cache/clip/ViT-B-32.pt, the file of OpenCLIP's
    download URL, a documented place) are TorchScript archives: open_clip's
    torch.load(weights_only=True) refused them ('Cannot use weights_only=True with
    TorchScript archives'), as a tag's file there or as checkpoint:."""
    import warnings

    src = _fresh(model=tiny, pretrained="random", seed=11)
    model = src._load()[0]
    image, text = torch.zeros(1, 3, 32, 32), torch.zeros(1, 16, dtype=torch.long)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.jit.trace(model, (image, text), strict=False, check_trace=False).save(
            str(tmp_path / "tiny-openai.pt")
        )
    fake = {"url": "https://example.invalid/x/tiny-openai.pt", "hf_hub": "", "quick_gelu": False}
    monkeypatch.setattr(
        open_clip, "get_pretrained_cfg", lambda m, t: fake if t == "faketag" else {}
    )
    ref = src.encode_text(["chair", "sofa"])
    for kw in (
        {"pretrained": "faketag", "cache_dir": str(tmp_path)},
        {"checkpoint": str(tmp_path / "tiny-openai.pt")},
    ):
        np.testing.assert_array_equal(_fresh(model=tiny, **kw).encode_text(["chair", "sofa"]), ref)
