"""``open-clip`` encoder: any OpenCLIP text tower, offline by default (``[clip]`` extra).

Presets name the text tower that built each map family:

============== ==================== ===================== =====
preset         open_clip model      pretrained tag        dim
============== ==================== ===================== =====
lseg           ViT-B-32             openai                512
openseg        ViT-L-14-336         openai                768
conceptfusion  ViT-H-14             laion2b_s32b_b79k     1024
============== ==================== ===================== =====
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..core.config import check_device
from ..core.errors import ConfigError, EncoderError, closest
from ..core.interfaces import Encoder
from ._open_clip_weights import (
    HF_CONFIG_NAME,
    HF_WEIGHT_NAMES,
    Resolved,
    hf_cached_file,
    is_tag,
    is_torchscript,
    load_torchscript_weights,
    locate_tag,
    looks_like_path,
    missing_weights_error,
    network_timeout,
    open_clip_logs,
    seeded,
)
from ._runtime import (
    PROGRESS_MIN,
    hf_offline,
    legacy_weights_identity,
    read_json,
    require,
    resolve_device,
    weights_identity,
)

log = logging.getLogger(__name__)

#: preset -> (open_clip model, pretrained tag, embedding dim, map family).
OPEN_CLIP_PRESETS: dict[str, tuple[str, str, int, str]] = {
    "lseg": ("ViT-B-32", "openai", 512, "LSeg / VLMaps"),
    "openseg": ("ViT-L-14-336", "openai", 768, "OpenSeg"),
    "conceptfusion": ("ViT-H-14", "laion2b_s32b_b79k", 1024, "ConceptFusion"),
}
PRECISIONS = ("auto", "fp32", "fp16", "bf16")
#: Values of ``pretrained`` meaning "random weights" even when a preset names a tag.
RANDOM = ("random", "none")
_LOADED: dict[tuple[Any, ...], tuple[Any, Any, Any]] = {}


class OpenClipEncoder(Encoder):
    """An OpenCLIP text tower (and image tower, for image queries).

    Parameters
    ----------
    model
        open_clip model name (``ViT-B-32``), ``hf-hub:org/name`` (must already be in the
        local Hugging Face cache) or ``local-dir:/path`` (``open_clip_config.json`` +
        weights). Default: the preset's.
    pretrained
        A pretrained tag (``openai``, ``laion2b_s32b_b79k``), a local checkpoint path, or
        None. With a preset, None means the preset's tag; without one, None (or
        ``"random"``) builds random weights (for tests only: the embeddings mean nothing).
    preset
        ``lseg`` (512), ``openseg`` (768) or ``conceptfusion`` (1024).
    checkpoint
        Local weights file (a ``state_dict`` of this architecture). Overrides where the
        weights come from; a tag's QuickGELU and preprocessing settings still apply.
    device
        ``auto`` (cuda, then mps, then cpu), ``cpu``, ``cuda``, ``cuda:N`` or ``mps``.
    batch_size
        Strings (or images) per forward pass.
    precision
        ``auto`` (fp16 on CUDA, fp32 elsewhere), ``fp32``, ``fp16`` or ``bf16``.
    offline
        True (default): never touch the network; missing weights fail at once with the
        expected file name and location. A number: allow downloads, with that socket
        timeout in seconds. False: allow downloads with a 60 s timeout.
    cache_dir
        Download/cache directory passed to OpenCLIP (default: its own).
    seed
        Seed of the random initialisation (random weights are reproducible).
    """

    name = "open-clip"

    def __init__(
        self,
        model: str | None = None,
        pretrained: str | None = None,
        preset: str | None = None,
        checkpoint: str | None = None,
        device: str = "auto",
        batch_size: int = 256,
        precision: str = "auto",
        offline: bool | float = True,
        cache_dir: str | None = None,
        seed: int = 0,
    ) -> None:
        if preset is not None and preset not in OPEN_CLIP_PRESETS:
            guess = closest(str(preset), OPEN_CLIP_PRESETS)
            hint = f" Did you mean {guess!r}?" if guess else ""
            raise ConfigError(
                f"open-clip preset {preset!r} is unknown. Known: "
                f"{', '.join(OPEN_CLIP_PRESETS)}.{hint}"
            )
        if precision not in PRECISIONS:
            raise ConfigError(f"precision must be one of {PRECISIONS}; got {precision!r}.")
        if int(batch_size) < 1:
            raise ConfigError(f"batch_size must be >= 1; got {batch_size!r}.")
        if model is None and preset is None:
            raise ConfigError(
                "open-clip needs 'model' (an open_clip name such as ViT-B-32) or 'preset' "
                f"({', '.join(OPEN_CLIP_PRESETS)})."
            )
        if str(model).startswith(("hf-hub:", "local-dir:")) and (
            checkpoint is not None or pretrained is not None
        ):
            given = "checkpoint" if checkpoint is not None else "pretrained"
            raise ConfigError(
                f"open-clip model {model!r} brings its own weights ({HF_CONFIG_NAME} and a "
                f"weight file), so its '{given}' would be ignored. Remove '{given}', or give "
                "the architecture as 'model' (an open_clip name such as ViT-B-32) with "
                "'checkpoint: FILE'."
            )
        self.preset = preset
        p_model, p_tag = (OPEN_CLIP_PRESETS[preset][:2]) if preset else (None, None)
        self.model = str(model or p_model)
        self.pretrained = pretrained if pretrained is not None else p_tag
        self.checkpoint = checkpoint
        self.requested_device = check_device(device, "encoder 'open-clip': 'device'")
        self.batch_size = int(batch_size)
        self.precision = precision
        self.offline = offline
        self.cache_dir = cache_dir
        self.seed = int(seed)
        self._device: str | None = None
        self._loaded: tuple[Any, Any, Any] | None = None
        self._resolved = self._resolve()
        if preset and self.dim != OPEN_CLIP_PRESETS[preset][2]:
            log.warning(
                "open-clip preset %s with model %s gives %d-d, not %d-d embeddings",
                preset,
                self.model,
                self.dim,
                OPEN_CLIP_PRESETS[preset][2],
            )

    # ------------------------------------------------------------------ resolution
    @property
    def _offline(self) -> bool:
        return self.offline is True

    def _timeout(self) -> float:
        if self.offline is False or self.offline is None:
            return 60.0
        return float(self.offline)

    def _resolve(self) -> Resolved:
        """Decide where the weights come from, reading only local files."""
        open_clip = require("open_clip", "clip")
        what = f"{self.model}" + (f" / {self.pretrained}" if self.pretrained else "")
        if self.model.startswith(("hf-hub:", "local-dir:")):
            schema, ident = self.model.split(":", 1)
            if schema == "local-dir":
                d = Path(ident).expanduser()
                # open_clip loads the first *.safetensors, *.bin or *.pth; with none it
                # builds random weights with a warning
                has_weights = d.is_dir() and any(
                    p.is_file() for s in (".safetensors", ".bin", ".pth") for p in d.glob(f"*{s}")
                )
                if not (d / HF_CONFIG_NAME).is_file() or not has_weights:
                    raise EncoderError(
                        f"open-clip local-dir {d} needs {HF_CONFIG_NAME} and a weights file "
                        f"({' or '.join(HF_WEIGHT_NAMES)})."
                    )
                return Resolved(self.model, schema=schema, identity=weights_identity(d), weights=d)
            config = hf_cached_file(ident, (HF_CONFIG_NAME,), self.cache_dir)
            weights = hf_cached_file(ident, HF_WEIGHT_NAMES, self.cache_dir)
            if (config is None or weights is None) and self._offline:
                raise missing_weights_error(
                    self.model,
                    [
                        f"the Hugging Face cache as repo {ident!r} with files {HF_CONFIG_NAME!r} "
                        f"and {' or '.join(repr(n) for n in HF_WEIGHT_NAMES)} (on a machine "
                        f"with network: hf download {ident}), or a folder with those files "
                        "given as model: local-dir:/path"
                    ],
                    self.model,
                    fix_timeout=True,
                    checkpoint=False,
                )
            ident_w: Any = weights_identity(weights) if weights is not None else self.model
            if weights is not None and config is not None:
                # the config is the architecture (QuickGELU too): a revision with another
                # config and the same weight file is another function
                config_sha = hashlib.sha256(config.read_bytes()).hexdigest()[:16]
                ident_w = {**ident_w, "config": config_sha}
            return Resolved(self.model, schema=schema, identity=ident_w, weights=weights)
        if self.model.replace("/", "-") not in open_clip.list_models():
            guess = closest(self.model, open_clip.list_models())
            hint = f" Did you mean {guess!r}?" if guess else ""
            raise ConfigError(
                f"open_clip has no model {self.model!r}.{hint} See open_clip.list_models()."
            )
        tag = self.pretrained
        ckpt = self.checkpoint
        if tag is not None and str(tag).lower() not in RANDOM and not is_tag(self.model, tag):
            if Path(str(tag)).expanduser().exists() or looks_like_path(str(tag)):
                ckpt, tag = ckpt or str(tag), None
            else:
                tags = open_clip.list_pretrained_tags_by_model(self.model)
                guess = closest(str(tag), tags)
                hint = f" Did you mean {guess!r}?" if guess else ""
                raise ConfigError(
                    f"open-clip pretrained {tag!r} is neither a tag of {self.model} "
                    f"(known: {', '.join(tags) or 'none'}) nor an existing file.{hint}"
                )
        tag_cfg = dict(open_clip.get_pretrained_cfg(self.model, tag) or {}) if tag else {}
        if ckpt is not None:
            path = Path(str(ckpt)).expanduser()
            if not path.is_file():
                what = "is a folder" if path.is_dir() else "does not exist"
                raise EncoderError(
                    f"open-clip checkpoint {path} {what}. Give the path of a "
                    f"{self.model} state-dict file (.pt, .bin or .safetensors)."
                )
            return Resolved(
                self.model,
                checkpoint=path,
                tag=tag,
                tag_cfg=tag_cfg,
                identity=weights_identity(path),
                weights=path,
            )
        if tag is None or str(tag).lower() in RANDOM:
            if tag is None and self.preset is None:
                log.warning(
                    "open-clip %s has no pretrained weights: random initialisation "
                    "(seed %d); its embeddings are meaningless",
                    self.model,
                    self.seed,
                )
            return Resolved(self.model, random=True, identity={"random_seed": self.seed})
        found, places = locate_tag(self.model, tag, self.cache_dir)
        if found is None and self._offline:
            raise missing_weights_error(what, places, self.model, fix_timeout=True)
        identity = weights_identity(found) if found is not None else {"tag": tag}
        return Resolved(
            self.model,
            checkpoint=found,
            tag=tag,
            tag_cfg=tag_cfg,
            identity=identity,
            weights=found,
        )

    # ------------------------------------------------------------------ loading
    @property
    def device(self) -> str:  # type: ignore[override]
        if self._device is None:
            self._device = resolve_device(self.requested_device)
        return self._device

    @property
    def resolved_precision(self) -> str:
        if self.precision != "auto":
            return self.precision
        return "fp16" if self.device.startswith("cuda") else "fp32"

    def _load(self) -> tuple[Any, Any, Any]:
        """(model, tokenizer, image preprocess), built once per process and settings."""
        if self._loaded is not None:
            return self._loaded
        key = (self.fingerprint(), self.device)
        if key in _LOADED:
            self._loaded = _LOADED[key]
            return self._loaded
        open_clip = require("open_clip", "clip")
        import torch

        r = self._resolved
        kwargs: dict[str, Any] = dict(
            device=self.device,
            precision=self.resolved_precision,
            pretrained_text=False,
            pretrained_image=False,
            cache_dir=self.cache_dir,
        )
        if r.schema is None:
            kwargs["pretrained"] = str(r.checkpoint) if r.checkpoint is not None else None
            if r.tag_cfg.get("quick_gelu"):
                kwargs["force_quick_gelu"] = True
            # create_model_and_transforms takes the tag's preprocessing as image_* keywords
            # (it builds force_preprocess_cfg from them itself)
            for k in ("mean", "std", "interpolation", "resize_mode"):
                if k in r.tag_cfg:
                    kwargs[f"image_{k}"] = r.tag_cfg[k]
            if r.checkpoint is None and not r.random:  # download allowed (offline is a timeout)
                kwargs["pretrained"] = r.tag
        jit = r.checkpoint is not None and is_torchscript(r.checkpoint)
        if jit:  # OpenAI's own file: its weights are loaded once the model is built
            kwargs["pretrained"] = None
        net: Any = hf_offline() if self._offline else network_timeout(self._timeout())
        log.info(
            "loading open_clip %s (%s) on %s, %s",
            self.model,
            r.checkpoint or r.tag or ("random" if r.random else r.schema),
            self.device,
            self.resolved_precision,
        )
        try:
            init = seeded(torch, self.seed) if r.random else contextlib.nullcontext()
            with net, open_clip_logs(log, r.random or jit), init:
                model, _, preprocess = open_clip.create_model_and_transforms(self.model, **kwargs)
                if jit:
                    load_torchscript_weights(model, r.checkpoint)
                tokenizer = open_clip.get_tokenizer(self.model, cache_dir=self.cache_dir)
        except EncoderError:
            raise
        except Exception as exc:  # noqa: BLE001 - report any loader failure with its source
            where = r.checkpoint or r.tag or self.model
            msg = f"Could not load open_clip {self.model} from {where}: {_reason(exc)}"
            if r.checkpoint is not None and r.schema is None:
                msg += (
                    f"{'' if msg.endswith(('.', '!', '?')) else '.'} The file must be a state dict of {self.model} (the architecture "
                    "'model' or 'preset' names; .pt, .bin or .safetensors, optionally under "
                    "'state_dict'): set 'model' to the one it was trained as."
                )
            raise EncoderError(msg) from None
        model.eval()
        self._loaded = (model, tokenizer, preprocess)
        _LOADED[key] = self._loaded
        return self._loaded

    # ------------------------------------------------------------------ Encoder API
    @property
    def dim(self) -> int:
        cfg = self._model_cfg()
        if cfg and "embed_dim" in cfg:
            return int(cfg["embed_dim"])
        model = self._load()[0]
        return int(model.text_projection.shape[-1])

    def _model_cfg(self) -> dict[str, Any] | None:
        r = self._resolved
        if r.schema == "local-dir":
            return (read_json(Path(self.model.split(":", 1)[1]) / HF_CONFIG_NAME) or {}).get(
                "model_cfg"
            )
        if r.schema == "hf-hub":
            p = hf_cached_file(self.model.split(":", 1)[1], (HF_CONFIG_NAME,), self.cache_dir)
            return (read_json(p) or {}).get("model_cfg") if p else None
        import open_clip

        return open_clip.get_model_config(self.model.replace("/", "-"))

    def encode_text(self, texts: Sequence[str]) -> np.ndarray:
        """Embed ``texts``; returns ``(len(texts), dim)`` float32 with unit-norm rows."""
        texts = [str(t) for t in texts]
        if not texts:
            return np.zeros((0, self.dim), dtype=np.float32)
        model, tokenizer, _ = self._load()
        import torch

        from ..core.progress import progress

        out = []
        total = len(texts) if len(texts) > PROGRESS_MIN else 0
        with torch.inference_mode(), progress(total, f"encoding {len(texts)} texts") as advance:
            for i in range(0, len(texts), self.batch_size):
                part = texts[i : i + self.batch_size]
                tokens = tokenizer(part).to(self.device)
                emb = model.encode_text(tokens).float()
                out.append(torch.nn.functional.normalize(emb, dim=-1).cpu().numpy())
                advance(len(part))
        return np.ascontiguousarray(np.concatenate(out), dtype=np.float32)

    def encode_images(self, images: Any) -> np.ndarray:
        """Global image embeddings ``(n, dim)`` float32, unit rows.

        ``images`` is a list of PIL images, ``(H, W, 3)`` uint8 arrays or file paths.
        """
        model, _, preprocess = self._load()
        import torch
        from PIL import Image

        if isinstance(images, (str, Path, np.ndarray)) and not (
            isinstance(images, np.ndarray) and images.ndim == 4
        ):
            images = [images]
        pil = []
        for im in images:
            if isinstance(im, (str, Path)):
                im = Image.open(im)
            elif isinstance(im, np.ndarray):
                im = Image.fromarray(np.asarray(im, dtype=np.uint8))
            pil.append(im.convert("RGB"))
        if not pil:
            return np.zeros((0, self.dim), dtype=np.float32)
        dtype = next(model.parameters()).dtype
        out = []
        with torch.inference_mode():
            for i in range(0, len(pil), self.batch_size):
                batch = torch.stack([preprocess(im) for im in pil[i : i + self.batch_size]])
                emb = model.encode_image(batch.to(self.device, dtype=dtype)).float()
                out.append(torch.nn.functional.normalize(emb, dim=-1).cpu().numpy())
        return np.ascontiguousarray(np.concatenate(out), dtype=np.float32)

    def config(self) -> dict[str, Any]:
        return {
            "model": self.model,
            "pretrained": self.pretrained,
            "preset": self.preset,
            "checkpoint": str(self.checkpoint) if self.checkpoint else None,
            "precision": self.precision,
        }

    def fingerprint(self) -> str:
        """Architecture, weights identity, QuickGELU, precision and normalisation."""
        return self._fingerprint(self._resolved.identity)

    def earlier_fingerprints(self) -> list[str]:
        """The fingerprint as quash-plugins wrote it before weights were named by their
        content (their path and mtimes, :func:`legacy_weights_identity`), and for an
        ``hf-hub:`` model before its config was named too: maps built then with these
        weights are not warned about."""
        r = self._resolved
        if r.weights is None or not Path(r.weights).exists():
            return []
        earlier = [self._fingerprint(legacy_weights_identity(r.weights))]
        if r.schema == "hf-hub":  # before its open_clip_config.json was named too
            earlier.append(self._fingerprint(weights_identity(r.weights)))
        return earlier

    def _fingerprint(self, weights: Any) -> str:
        r = self._resolved
        ident = {
            "class": f"{type(self).__module__}.{type(self).__qualname__}",
            "model": self.model,
            "tag": r.tag,
            "weights": weights,
            "quick_gelu": bool(r.tag_cfg.get("quick_gelu")),
            "precision": self.resolved_precision,
            "normalized": True,
        }
        blob = json.dumps(ident, sort_keys=True, default=str).encode()
        return f"{self.name}-{hashlib.sha256(blob).hexdigest()[:16]}"

    @classmethod
    def conformance_params(cls, tmp_path: Path) -> dict[str, Any]:
        """Random weights of the smallest built-in text tower, on CPU."""
        return {"model": "ViT-B-32", "pretrained": "random", "device": "cpu"}


def _reason(exc: BaseException, limit: int = 400) -> str:
    """A loader's exception in one line: a state-dict mismatch lists every key (cut
    short), and an empty file or state dict raises an exception with no message (its
    type is given instead)."""
    text = " ".join(str(exc).split())
    if len(text) > limit:
        text = text[:limit].rsplit(" ", 1)[0] + " ..."
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__
