"""Where the classification pass runs (``device:``), and the maps kept on a device."""

from __future__ import annotations

import os
import weakref
from typing import Any

from ...core.config import check_device
from ...core.errors import QuashError


def pass_device(device: str | None) -> str | None:
    """The torch device of the classification pass, or None for the CPU block pass.

    ``cuda`` (or ``cuda:N``) asks for a GPU: an error naming the fix when torch or a CUDA
    GPU is missing. ``auto`` takes the GPU when an NVIDIA device node exists and torch
    sees a GPU; torch is not imported otherwise. ``cpu`` and ``mps`` (which only the text
    encoder uses: the pass has no Apple-GPU executor) keep the CPU pass. Any other value
    is refused (:func:`~quash_plugins.core.config.check_device`).

    Examples
    --------
    >>> pass_device("cpu") is None
    True
    """
    text = check_device(device, "device")
    kind, _, index = text.partition(":")
    if kind in ("cpu", "mps"):
        return None
    if kind == "auto":
        if not os.path.exists("/dev/nvidiactl") or _cuda_unavailable("") is not None:
            return None
        return "cuda"
    why = _cuda_unavailable(index)
    if why is not None:
        raise QuashError(
            f"device {text!r}: {why}; use device: cpu "
            "(or auto, which takes a GPU only when there is one)."
        )
    return text


def device_unavailable(device: str | None) -> str | None:
    """Why ``device`` cannot be used on this machine, in words, or None when it can.

    ``auto`` and ``cpu`` always can, and torch is not imported for them. ``cuda`` needs
    torch to see a CUDA GPU, ``cuda:N`` at least N + 1 of them, and ``mps`` torch's Apple
    MPS backend. A value that is no device at all is refused by
    :func:`~quash_plugins.core.config.check_device` (ConfigError), as everywhere.

    Examples
    --------
    >>> device_unavailable("cpu") is None
    True
    """
    text = check_device(device, "device")
    kind, _, index = text.partition(":")
    if kind in ("auto", "cpu"):
        return None
    if kind == "mps":
        try:
            import torch
        except ImportError:
            return _NO_TORCH
        mps = getattr(torch.backends, "mps", None)
        if mps is not None and mps.is_available():
            return None
        return "torch sees no Apple MPS device on this machine"
    return _cuda_unavailable(index)


_NO_TORCH = 'it needs PyTorch, which is not installed (pip install "quash-plugins[clip]")'


def _cuda_unavailable(index: str) -> str | None:
    """Why CUDA GPU number ``index`` (``""``: any) is not on this machine, or None.

    The one check behind :func:`pass_device` (which raises it) and
    :func:`device_unavailable` (which returns it)."""
    try:
        import torch
    except ImportError:
        return _NO_TORCH
    if not torch.cuda.is_available():
        return "torch sees no CUDA GPU on this machine"
    count = torch.cuda.device_count()
    if index and int(index) >= count:
        return f"torch sees {count} CUDA GPU(s) on this machine, numbered from 0"
    return None


_MAPS: dict[tuple[int, str], tuple[Any, Any]] = {}


def device_map(lmap: Any, device: str, chunk_bytes: int = 64 * 2**20) -> Any:
    """The map's :class:`~quash_plugins.engine.device.DeviceMap` on ``device``: uploaded
    on first use (as stored: float16 stays float16) and kept while the map object lives,
    so later queries, ``query_many`` included, run on the device copy."""
    key = (id(lmap), str(device))
    hit = _MAPS.get(key)
    if hit is not None and hit[0]() is lmap:
        return hit[1]
    for k in [k for k, (ref, _) in _MAPS.items() if ref() is None]:
        del _MAPS[k]  # maps that are gone free their device memory
    from ._device_map import DeviceMap

    dmap = DeviceMap(lmap, device, chunk_bytes=chunk_bytes)
    _MAPS[key] = (weakref.ref(lmap), dmap)
    return dmap


def release_device_maps() -> None:
    """Forget every kept device map (their memory is freed once nothing else holds them)."""
    _MAPS.clear()
