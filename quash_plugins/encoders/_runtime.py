"""Helpers shared by the torch-based encoders: devices, offline loading, weight identity.

Nothing here imports torch at module level.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib
import json
import logging
import os
import struct
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from ..core.atomic import atomic_write_text
from ..core.cache_dirs import cache_dir, make_private_dirs
from ..core.errors import ConfigError, EncoderError, UsageError

log = logging.getLogger(__name__)

#: Environment variables that put the Hugging Face libraries into offline mode.
OFFLINE_ENV = ("HF_HUB_OFFLINE", "TRANSFORMERS_OFFLINE", "HF_DATASETS_OFFLINE")

#: Weight files whose sizes and content digests enter a fingerprint.
_WEIGHT_SUFFIXES = (".safetensors", ".bin", ".pt", ".pth", ".ckpt", ".msgpack", ".h5")
#: Small config files whose content enters a fingerprint.
_CONFIG_NAMES = (
    "config.json",
    "modules.json",
    "config_sentence_transformers.json",
    "sentence_bert_config.json",
    "tokenizer_config.json",
    "open_clip_config.json",
)


def require(module: str, extra: str) -> Any:
    """Import ``module`` or raise an :class:`EncoderError` naming the extra to install.
    Once imported, the Hugging Face libraries log through ``quash``'s handlers
    (:func:`route_library_logs`)."""
    try:
        imported = importlib.import_module(module)
    except ImportError as exc:
        raise EncoderError(
            f"This encoder needs the Python package {module!r} ({exc}). Install it with "
            f'pip install "quash-plugins[{extra}]"'
        ) from None
    route_library_logs()
    return imported


#: The loggers of the libraries the torch encoders load their models through; each
#: puts a handler of its own on its logger when imported.
#: Encodes of more strings than this show progress (the vocabulary heuristic's ~1,100
#: names; the adjectives heuristic's ~1,000 phrases took 12 s on 2 cores unannounced at a
#: threshold of 1,000): a bar on a terminal, else a line every ~10 % after 2 s.
PROGRESS_MIN = 256
LIBRARY_LOGGERS = ("huggingface_hub", "transformers", "sentence_transformers")


class _ToPackageHandlers(logging.Handler):
    """Hands a library's record to the handlers of the ``quash_plugins`` logger, as they
    are when it is emitted (the format, redaction and escaping of ``quash``'s own lines):
    under ``--quiet`` (that logger at WARNING or above) only errors, else the library's
    warnings too (and whatever its own level lets through), each line prefixed with the
    library's name."""

    def emit(self, record: logging.LogRecord) -> None:
        ours = logging.getLogger("quash_plugins")
        if not _command_logging(ours):  # no longer the command's: as Python would
            if logging.lastResort is not None and record.levelno >= logging.lastResort.level:
                logging.lastResort.handle(record)
            return
        if ours.getEffectiveLevel() >= logging.WARNING and record.levelno < logging.ERROR:
            return
        # said as whose it is, as open_clip's are ("huggingface_hub: Retrying in 1s ...")
        library = record.name.split(".", 1)[0]
        record = logging.makeLogRecord(
            {**record.__dict__, "msg": f"{library}: {record.getMessage()}", "args": None}
        )
        for handler in ours.handlers:
            if record.levelno >= handler.level:
                handler.handle(record)


def _command_logging(ours: logging.Logger) -> bool:
    """Whether the ``quash`` command set up the package's logging: handlers of its own,
    not propagated."""
    return not ours.propagate and any(not isinstance(h, logging.NullHandler) for h in ours.handlers)


def route_library_logs() -> None:
    """Send the Hugging Face libraries' log lines (the hub's "Retrying in 2s" and request
    errors, transformers' warnings) through the ``quash`` command's logging, in place of
    the handlers the libraries print with themselves, so that ``--quiet`` silences their
    warnings and the default and ``--verbose`` show them as ``WARNING  ...`` lines.

    Only where the command set up logging (:func:`quash_plugins.cli._output.setup_logging`
    gives the ``quash_plugins`` logger its own handlers and stops its propagation): a
    program that uses the package and configures logging itself is left alone."""
    if not _command_logging(logging.getLogger("quash_plugins")):
        return
    for name in LIBRARY_LOGGERS:
        lib = logging.getLogger(name)
        if (
            not any(isinstance(h, _ToPackageHandlers) for h in lib.handlers)
            or len(lib.handlers) > 1
        ):
            lib.handlers[:] = [_ToPackageHandlers()]
        lib.propagate = False


def resolve_device(device: str | None) -> str:
    """Turn ``"auto"`` (or None) into ``cuda``, ``mps`` or ``cpu``; validate explicit devices.

    Raises
    ------
    ConfigError
        When the string is not a torch device.
    EncoderError
        When the requested accelerator is not available on this machine.
    """
    torch = require("torch", "clip")
    if device is None or str(device).strip().lower() in ("", "auto"):
        if torch.cuda.is_available():
            return "cuda"
        mps = getattr(torch.backends, "mps", None)
        if mps is not None and mps.is_available():
            return "mps"
        return "cpu"
    device = str(device).strip()
    try:
        dev = torch.device(device)
    except (RuntimeError, ValueError):
        raise ConfigError(
            f"device {device!r} is not a torch device; use auto, cpu, cuda, cuda:N or mps."
        ) from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise EncoderError(
            f"device {device!r} was requested but CUDA is not available on this machine "
            "(torch.cuda.is_available() is False). Use device: auto or cpu."
        )
    if dev.type == "cuda" and dev.index is not None and dev.index >= torch.cuda.device_count():
        raise EncoderError(
            f"device {device!r} does not exist: this machine has "
            f"{torch.cuda.device_count()} CUDA device(s)."
        )
    if dev.type == "mps":
        mps = getattr(torch.backends, "mps", None)
        if mps is None or not mps.is_available():
            raise EncoderError(
                f"device {device!r} was requested but MPS is not available. Use auto or cpu."
            )
    return device


@contextlib.contextmanager
def hf_offline() -> Iterator[None]:
    """Force the Hugging Face libraries offline for the duration of the block.

    Sets ``HF_HUB_OFFLINE``/``TRANSFORMERS_OFFLINE`` and, because ``huggingface_hub``
    reads them once at import, also its module-level flag. Everything is restored after.
    """
    saved = {k: os.environ.get(k) for k in OFFLINE_ENV}
    for k in OFFLINE_ENV:
        os.environ[k] = "1"
    patched: list[tuple[Any, str, Any]] = []
    for modname in ("huggingface_hub.constants", "transformers.utils.hub"):
        mod = sys.modules.get(modname)
        for attr in ("HF_HUB_OFFLINE", "_is_offline_mode"):
            if mod is not None and isinstance(getattr(mod, attr, None), bool):
                patched.append((mod, attr, getattr(mod, attr)))
                setattr(mod, attr, True)
    try:
        yield
    finally:
        for mod, attr, value in patched:
            setattr(mod, attr, value)
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def safetensors_header_digest(path: Path) -> str | None:
    """SHA-256 of a safetensors file's JSON header (tensor names, dtypes, shapes, offsets)."""
    try:
        with open(path, "rb") as fh:
            (n,) = struct.unpack("<Q", fh.read(8))
            if n <= 0 or n > 100 * 2**20:
                return None
            return hashlib.sha256(fh.read(n)).hexdigest()[:16]
    except (OSError, struct.error):
        return None


def weights_identity(path: str | Path) -> dict[str, Any]:
    """The identity of the weights at ``path`` (a file or a model directory): what they
    are, not where they lie.

    Combines the content of small config files and, for every weight file, its path
    within ``path``, its size and the SHA-256 of its content (:func:`content_digest`:
    read once per file and remembered by path, size and mtime, so a later call reads no
    tensor data). The same weights installed in two virtual environments, copied, or
    reinstalled (a new mtime) have one identity, so a map built in one checkout is not
    called "built with another embedding function" in the other, and the text cache is
    shared; two fine-tunes of one architecture (the same sizes and safetensors header)
    do not.
    """
    sha, n_weights = _weights_digest(Path(path).expanduser(), _content_part)
    return {"files": n_weights, "sha": sha}


def legacy_weights_identity(path: str | Path) -> dict[str, Any]:
    """:func:`weights_identity` as quash-plugins named weights before it was content
    based (the resolved path, and each weight file's size, mtime and safetensors header):
    for ``earlier_fingerprints``, so maps and cache rows made then are still recognised."""
    path = Path(path).expanduser()
    sha, n_weights = _weights_digest(path, _legacy_part)
    return {"path": str(path.resolve()), "files": n_weights, "sha": sha}


def _content_part(p: Path) -> str:
    return f"{p.stat().st_size}:{content_digest(p)}"


def _legacy_part(p: Path) -> str:
    st = p.stat()
    header = (safetensors_header_digest(p) or "") if p.suffix == ".safetensors" else ""
    return f"{st.st_size}:{st.st_mtime_ns}{header}"


def _weights_digest(path: Path, weight_part: Any) -> tuple[str, int]:
    """The digest of the config files' content and ``rel:weight_part(file)`` of each
    weight file under ``path``, and the number of weight files."""
    root, files = _weight_files(path)
    h = hashlib.sha256()
    n_weights = 0
    for p in files:
        rel = p.relative_to(root).as_posix()
        if p.name in _CONFIG_NAMES:
            h.update(f"{rel}:".encode())
            h.update(p.read_bytes())
        elif p.suffix in _WEIGHT_SUFFIXES:
            h.update(f"{rel}:{weight_part(p)}".encode())
            n_weights += 1
    return h.hexdigest()[:16], n_weights


def _weight_files(path: Path) -> tuple[Path, list[Path]]:
    if path.is_file():
        return path.parent, [path]
    return path, sorted(p for p in path.rglob("*") if p.is_file())


#: Files larger than this log a line while their content is hashed (once per file).
_HASH_LOG_BYTES = 512 * 2**20


def content_digest(path: Path) -> str:
    """SHA-256 (16 hex digits) of the content of the file at ``path``, remembered under
    ``<cache>/weight-digests`` by the file's resolved path, size, mtime and inode: a file
    is read once, not at every start (a ViT-H checkpoint is 4 GB). A memo that cannot be
    read or written is not used (the file is hashed each time); a changed file is a new
    key; a memo that is a symbolic link is not read."""
    st = path.stat()
    key = hashlib.sha256(
        f"{path.resolve()}|{st.st_size}|{st.st_mtime_ns}|{st.st_ino}".encode()
    ).hexdigest()[:32]
    memo = cache_dir("weight-digests") / key
    with contextlib.suppress(OSError, UnicodeDecodeError):
        if not memo.is_symlink() and memo.is_file():  # a planted link is not followed
            known = memo.read_text(encoding="ascii").strip()
            if len(known) == 16 and all(c in "0123456789abcdef" for c in known):
                return known
    if st.st_size > _HASH_LOG_BYTES:
        log.info("hashing %s (%.1f GB) once, to name these weights", path, st.st_size / 1e9)
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(8 * 2**20), b""):
            h.update(block)
    digest = h.hexdigest()[:16]
    with contextlib.suppress(OSError, UsageError):  # unwritable, or a planted link there
        make_private_dirs(memo.parent)
        atomic_write_text(memo, digest + "\n")
    return digest


def read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
