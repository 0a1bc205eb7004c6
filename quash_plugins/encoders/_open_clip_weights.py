"""Finding OpenCLIP weights on this machine, without the network, and saying where they go.

OpenCLIP fetches a pretrained tag either from the Hugging Face Hub (``org/repo`` with
``open_clip_model.safetensors`` or ``open_clip_pytorch_model.bin``; the hub cache is
``$HF_HUB_CACHE``, default ``~/.cache/huggingface/hub``) or, for tags with only a URL,
into ``~/.cache/clip/<file name from the URL>``. This module looks in exactly those
places, so a load in offline mode either finds the file or fails at once with a message
naming the file and where to put it.
"""

from __future__ import annotations

import contextlib
import logging
import os
import socket
import sys
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..core.errors import EncoderError

#: File names OpenCLIP looks for in a Hugging Face repository, preferred first.
HF_WEIGHT_NAMES = ("open_clip_model.safetensors", "open_clip_pytorch_model.bin")
HF_CONFIG_NAME = "open_clip_config.json"
#: Where OpenCLIP stores URL downloads when no cache_dir is given.
URL_CACHE_DIR = "~/.cache/clip"


@dataclass
class Resolved:
    """Where an encoder's weights come from.

    ``checkpoint`` is a local file to load (or None for random weights / schema models),
    ``tag_cfg`` the pretrained-tag configuration whose preprocessing and QuickGELU flag
    apply, ``identity`` what enters the fingerprint, and ``weights`` the file or folder
    it names (None when no weights are on disk), for the earlier fingerprints.
    """

    model_name: str
    checkpoint: Path | None = None
    tag: str | None = None
    tag_cfg: dict[str, Any] = field(default_factory=dict)
    random: bool = False
    schema: str | None = None
    identity: Any = None
    weights: Path | None = None


def hf_cache_dir(cache_dir: str | None = None) -> Path:
    if cache_dir:
        return Path(cache_dir).expanduser()
    try:
        from huggingface_hub import constants

        return Path(constants.HF_HUB_CACHE)
    except ImportError:
        return Path("~/.cache/huggingface/hub").expanduser()


def hf_cached_file(repo: str, names: tuple[str, ...], cache_dir: str | None) -> Path | None:
    """The first of ``names`` present in the local HF cache for ``repo`` (no network)."""
    try:
        from huggingface_hub import try_to_load_from_cache
    except ImportError:
        return None
    for name in names:
        try:
            hit = try_to_load_from_cache(repo, name, cache_dir=cache_dir)
        except Exception:  # noqa: BLE001 - malformed repo id or cache: treat as absent
            hit = None
        if isinstance(hit, str) and os.path.isfile(hit):
            return Path(hit)
    return None


def _hf_names(filename: str) -> tuple[str, ...]:
    if not filename:
        return HF_WEIGHT_NAMES
    if filename.endswith((".bin", ".pth")):
        return (filename[:-4] + ".safetensors", filename)
    return (filename,)


def locate_tag(model: str, tag: str, cache_dir: str | None) -> tuple[Path | None, list[str]]:
    """Find the local file for ``model``/``tag``; return it (or None) and where it may go."""
    import open_clip

    cfg = open_clip.get_pretrained_cfg(model, tag) or {}
    places: list[str] = []
    hub = cfg.get("hf_hub", "")
    if hub:
        # "org/repo/" names the default weight files; "org/repo/file.pt" one file.
        repo, filename = (hub[:-1], "") if hub.endswith("/") else os.path.split(hub)
        names = _hf_names(filename)
        hit = hf_cached_file(repo, names, cache_dir)
        if hit is not None:
            return hit, places
        places.append(
            f"the Hugging Face cache {hf_cache_dir(cache_dir)} as repo {repo!r}, file "
            f"{' or '.join(repr(n) for n in names)} (on a machine with network: "
            f"hf download {repo} {names[0]}; then copy the cache folder)"
        )
    url = cfg.get("url", "")
    if url:
        name = os.path.basename(url)
        target = Path(cache_dir or URL_CACHE_DIR).expanduser() / name
        if target.is_file():
            return target, places
        places.append(f"{target} (downloaded from {url})")
    return None, places


def missing_weights_error(
    what: str, places: list[str], model: str, fix_timeout: bool, checkpoint: bool = True
) -> EncoderError:
    """``checkpoint``: whether a local file given as ``checkpoint:`` would do (not for an
    ``hf-hub:`` model, which brings its own weights)."""
    lines = "; or ".join(places) if places else "a local checkpoint file"
    msg = f"OpenCLIP weights for {what} are not on this machine. Put the checkpoint in {lines}"
    if checkpoint:
        msg += f"; or pass any local {model} state-dict file as 'checkpoint: /path/to/file'"
    msg += "."
    if fix_timeout:
        msg += " To let OpenCLIP download it, set 'offline: 60' (a network timeout in seconds)."
    return EncoderError(msg)


@contextlib.contextmanager
def network_timeout(seconds: float) -> Iterator[None]:
    """Bound every socket operation and Hugging Face request made inside the block."""
    old = socket.getdefaulttimeout()
    socket.setdefaulttimeout(float(seconds))
    env = {k: os.environ.get(k) for k in ("HF_HUB_DOWNLOAD_TIMEOUT", "HF_HUB_ETAG_TIMEOUT")}
    for k in env:
        os.environ[k] = str(int(max(1, seconds)))
    consts = sys.modules.get("huggingface_hub.constants")
    saved = {}
    if consts is not None:
        for attr in env:
            if hasattr(consts, attr):
                saved[attr] = getattr(consts, attr)
                setattr(consts, attr, int(max(1, seconds)))
    try:
        yield
    finally:
        socket.setdefaulttimeout(old)
        for attr, value in saved.items():
            setattr(consts, attr, value)
        for k, v in env.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def is_tag(model: str, tag: str) -> bool:
    import open_clip

    return bool(open_clip.get_pretrained_cfg(model.replace("/", "-"), tag))


def looks_like_path(s: str) -> bool:
    return "/" in s or "\\" in s or s.endswith((".pt", ".pth", ".bin", ".safetensors", ".ckpt"))


@contextlib.contextmanager
def seeded(torch: Any, seed: int):
    """Reproducible random initialisation without disturbing the global RNG."""
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        yield


#: open_clip's warning when it built random weights: the encoder says so itself.
RANDOM_INIT_WARNING = "No pretrained weights loaded"


@contextlib.contextmanager
def open_clip_logs(log: logging.Logger, random: bool) -> Iterator[None]:
    """Re-log open_clip's log records on ``log`` for the duration of the block.

    open_clip logs on the root logger (``logging.warning(...)``), whose first call
    installs Python's own stderr handler: its lines (``WARNING:root:...``) bypassed this
    package's logging, ``--quiet`` and the redaction, and every later root record printed
    too. Inside the block the root logger has a handler (so none is installed) and its
    records from open_clip go to ``log``; its "No pretrained weights loaded" is dropped
    when ``random``: random weights were asked for (the encoder logs that itself), or the
    weights are loaded after open_clip built the model.
    """
    root = logging.getLogger()

    def reroute(record: logging.LogRecord) -> bool:
        if record.name != "root" or f"{os.sep}open_clip{os.sep}" not in record.pathname:
            return True
        message = record.getMessage()
        if not (random and message.startswith(RANDOM_INIT_WARNING)):
            log.log(record.levelno, "open_clip: %s", message)
        return False

    guard = None if root.handlers else logging.NullHandler()
    root.addFilter(reroute)
    if guard is not None:
        root.addHandler(guard)
    try:
        yield
    finally:
        root.removeFilter(reroute)
        if guard is not None:
            root.removeHandler(guard)


def is_torchscript(path: Path) -> bool:
    """Whether ``path`` is a TorchScript archive, as OpenAI's own checkpoints are (the
    files of OpenCLIP's download URLs, ``~/.cache/clip/ViT-B-32.pt``)."""
    import zipfile

    try:
        with zipfile.ZipFile(path) as z:
            return any(n.endswith("/constants.pkl") or "/code/" in n for n in z.namelist())
    except (OSError, zipfile.BadZipFile):
        return False


def load_torchscript_weights(model: Any, path: Path) -> None:
    """Load a TorchScript archive's weights into ``model``, as open_clip's OpenAI loader
    reads them: open_clip's ``torch.load(weights_only=True)`` refuses such archives."""
    import warnings

    import torch

    with warnings.catch_warnings():  # torch's deprecation of jit.load is not the user's
        warnings.simplefilter("ignore", FutureWarning)
        state = torch.jit.load(str(path), map_location="cpu").state_dict()
    for key in ("input_resolution", "context_length", "vocab_size"):
        state.pop(key, None)
    transient = {k for k, _ in model.named_buffers()} - set(model.state_dict())
    model.load_state_dict({k: v for k, v in state.items() if k not in transient})
