"""A plain ``.npy`` array read for a map: memory-mapped, never unpickled, and refused
with the file, the field and the fix (a re-save for an array of Python objects, a new
copy for a file cut short)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..core.errors import MapFormatError


def npy_fix(
    path: Path,
    exc: BaseException,
    name: str = "features",
    what: str = "frame",
    again: str = "copy or extract",
) -> str:
    """The fix for a ``.npy`` that ``np.load`` refused: re-save an array of Python
    objects as numbers (``name`` is the array in the example), or copy a cut-short file
    again (``what`` names it: that frame, that file; ``again`` how: copy or export)."""
    if "object" in str(exc).lower():  # numpy: "Python objects in dtype", "Object arrays"
        return (
            f"It holds Python objects, not numbers: re-save the {what} as a numeric "
            f"array, np.save('{path.name}', np.asarray({name}, np.float32))."
        )
    return f"The file may be damaged or truncated (an interrupted copy): {again} that {what} again."


def load_npy(
    path: Path,
    field: str | None = None,
    *,
    name: str = "features",
    what: str = "file",
    again: str = "copy or extract",
    mmap: bool = True,
) -> np.ndarray:
    """``np.load(path)`` memory-mapped (``mmap``), without pickles; numpy's refusal is
    a :class:`MapFormatError` naming the file, the ``field`` it holds and the fix."""
    try:
        return np.load(path, mmap_mode="r" if mmap else None, allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        held = f" (field {field!r})" if field else ""
        fix = npy_fix(path, exc, name, what, again)
        raise MapFormatError(f"{path}{held}: not a readable .npy array ({exc}). {fix}") from None
