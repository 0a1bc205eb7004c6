"""Safe ``torch.load`` of OpenScene's files: tensors only, or plain numpy arrays.

A fused-feature ``.pt`` is loaded with ``torch.load(weights_only=True)``, memory-mapped
where torch can; a scene's ``.pth`` tuple of numpy arrays with ``weights_only=True``
plus :func:`numpy_allow_list`, exactly what numpy needs to rebuild arrays. Anything else
in the pickle (a class, a function such as ``os.system``) is refused before it runs,
with a :class:`MapFormatError` naming the file and how to re-save it. torch is imported
on first use only.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import MapFormatError, QuashError
from ._torch_errors import first_line, is_weights_only_error, weights_only_refusal


def _torch() -> Any:
    try:
        import torch
    except ImportError:
        raise QuashError(
            'Reading OpenScene maps needs torch: pip install "quash-plugins[clip]"'
        ) from None
    return torch


def numpy_allow_list() -> list[Any]:
    """What ``torch.load(weights_only=True)`` must allow to rebuild plain numpy arrays.

    Exactly the array reconstructor (under its numpy 2 name and, as a ``(function,
    name)`` pair, its numpy 1 name), ``ndarray``, ``dtype``, numpy's scalar reconstructor
    and the dtype classes of the numeric types. Nothing that can run other code.
    """
    core = getattr(np, "_core", None) or np.core  # numpy 2, else numpy 1
    multiarray = core.multiarray
    allowed: list[Any] = [multiarray._reconstruct, multiarray.scalar, np.ndarray, np.dtype]
    codes = ("b1", "u1", "u2", "u4", "u8", "i1", "i2", "i4", "i8", "f2", "f4", "f8")
    allowed += sorted({type(np.dtype(c)) for c in codes} - {np.dtype}, key=str)
    if multiarray.__name__ != "numpy.core.multiarray":  # files pickled under numpy 1.x
        allowed.append((multiarray._reconstruct, "numpy.core.multiarray._reconstruct"))
        allowed.append((multiarray.scalar, "numpy.core.multiarray.scalar"))
    return allowed


def load_safe(path: Path, what: str, numpy_arrays: bool = False) -> Any:
    """``torch.load(path, weights_only=True)``, with :func:`numpy_allow_list` when asked.

    Any refusal or read error becomes a :class:`MapFormatError` naming the file.
    """
    torch = _torch()
    try:
        with warnings.catch_warnings():  # torch warns about pickle protocols it reads anyway
            warnings.filterwarnings("ignore", message="Detected pickle protocol")
            return _load(torch, path, numpy_arrays)
    except QuashError:
        raise
    except Exception as exc:  # noqa: BLE001 - torch raises many types for bad files
        raise _load_error(exc, path, what) from None


def _load(torch: Any, path: Path, numpy_arrays: bool) -> Any:
    if numpy_arrays:
        safe_globals = getattr(torch.serialization, "safe_globals", None)
        if safe_globals is None:  # pragma: no cover - torch < 2.5
            raise QuashError(
                f"{path}: reading OpenScene's .pth needs torch >= 2.5 "
                "(torch.serialization.safe_globals)."
            )
        with safe_globals(numpy_allow_list()):
            return torch.load(path, map_location="cpu", weights_only=True)
    try:
        return torch.load(path, map_location="cpu", weights_only=True, mmap=True)
    except RuntimeError as exc:  # legacy (non-zip) files cannot be memory-mapped
        if "mmap" not in str(exc):
            raise
        return torch.load(path, map_location="cpu", weights_only=True)


#: The safe fix for a refused file, by what it is.
_SAFE_FIX = {
    "fused-feature file": (
        "Re-save it as OpenScene's save_fused_feature does, tensors only: "
        "torch.save({'feat': feat.half(), 'mask_full': mask_full}, PATH); or save the "
        "per-point features with np.save as <scene>_openscene_feat_<type>.npy."
    ),
    "scene file": (
        "Re-save it as OpenScene's preprocessing does, a tuple of numpy arrays: "
        "torch.save((coords, colors, labels), PATH); or give the points with "
        "points=PATH (a .ply, or a .npy of (N, 3) coordinates)."
    ),
}


def _load_error(exc: Exception, path: Path, what: str) -> MapFormatError:
    if is_weights_only_error(exc):
        return weights_only_refusal(
            exc,
            path,
            what,
            _SAFE_FIX.get(what, "Re-save it as plain tensors or numpy arrays."),
            allowed="tensors and plain numpy arrays, in plain containers,",
        )
    return MapFormatError(f"{path}: not a readable {what} ({first_line(exc)}).")
