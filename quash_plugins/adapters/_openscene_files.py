"""OpenScene's files: which file is which, and the scene's points.

:func:`is_fused_file` and :func:`is_scene_file` tell a fused-feature ``.pt`` and a
scene's preprocessed ``.pth`` from their bytes, never unpickling them;
:func:`find_points` finds the scene's points beside its features, and
:func:`read_points` reads them (OpenScene's ``.pth`` tuple, a ``.ply`` or a ``.npy``).
"""

from __future__ import annotations

import logging
import re
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import MapFormatError, QuashError
from ..core.once import first_time
from ._npy import load_npy
from ._rows import colors_to_uint8
from ._torch_load import load_safe
from ._vlmaps_common import check_labels

log = logging.getLogger(__name__)

#: Label values OpenScene ignores: 255 in the preprocessed files, -100 in some loaders.
IGNORE_LABELS = (255, -100)
#: ``<scene>_<n>.pt`` (``save_fused_feature``); the scene id is what precedes ``_<n>``.
FUSED = re.compile(r"^(?P<scene>.+)_(?P<n>\d+)\.pt$")
NUMPY_FEAT = re.compile(r"^(?P<scene>.+)_openscene_feat_(?P<kind>[A-Za-z0-9]+)\.npy$")


#: The number torch's legacy (non-zip) ``torch.save`` pickles first, before the
#: protocol version, the system info and the object (``torch.serialization.MAGIC_NUMBER``).
LEGACY_MAGIC = 0x1950A86A20F9469CFC6C
#: Leading bytes read from a legacy file to find its object's keys.
LEGACY_HEAD = 1 << 16


def is_fused_file(path: Path) -> bool:
    """A ``torch.save`` file holding a dict whose pickle mentions ``feat`` or
    ``mask_full`` (read as bytes, never unpickled): a zip archive (torch >= 1.6), or a
    legacy file (``_use_new_zipfile_serialization=False``, which OpenScene's scripts
    write under older torch), see :func:`_is_legacy_fused`.

    One of OpenScene's two keys is enough, so that a fused file missing the other is read
    here and refused naming the missing field, not taken for a per-image feature map
    (``image-features`` reads bare tensors only, never a dict).
    """
    try:
        with zipfile.ZipFile(path) as z:
            names = [n for n in z.namelist() if n.endswith("/data.pkl")]
            if len(names) != 1 or z.getinfo(names[0]).file_size > 1 << 16:
                return False
            data = z.read(names[0])
    except zipfile.BadZipFile:
        return _is_legacy_fused(path)
    except (OSError, KeyError):
        return False
    # PROTO n, then EMPTY_DICT: the saved object is a dict (torch.save's pickle protocol 2)
    is_dict = data[:1] == b"\x80" and data[2:3] == b"}"
    return is_dict and (b"mask_full" in data or b"feat" in data)


def _is_legacy_fused(path: Path) -> bool:
    """A legacy ``torch.save`` file whose object is a dict with ``feat`` or
    ``mask_full``: four pickles in a row (the magic number :data:`LEGACY_MAGIC`, the
    protocol version, the system info, the object) before the raw storages. Their
    opcodes are walked with :func:`pickletools.genops`, which parses and never builds
    or runs anything; only the first :data:`LEGACY_HEAD` bytes are read."""
    import io
    import pickletools

    try:
        with open(path, "rb") as f:
            head = io.BytesIO(f.read(LEGACY_HEAD))
        pickles = []
        for _ in range(4):
            ops = []
            for op, arg, _pos in pickletools.genops(head):
                ops.append((op.name, arg))
            pickles.append(ops)
    except (OSError, ValueError, EOFError, UnicodeDecodeError):
        return False  # not a pickle, truncated, or an object bigger than the head
    magic = [arg for name, arg in pickles[0] if name not in ("PROTO", "FRAME", "STOP")]
    if magic != [LEGACY_MAGIC]:
        return False
    body = [(name, arg) for name, arg in pickles[3] if name not in ("PROTO", "FRAME")]
    if not body or body[0][0] != "EMPTY_DICT":
        return False
    strings = {arg for name, arg in body if isinstance(arg, str)}
    return bool(strings & {"feat", "mask_full"})


def is_scene_file(path: Path) -> bool:
    """A ``.pth`` that ``torch.save`` wrote of numpy arrays, not tensors, as OpenScene's
    preprocessed scene points ``(coords, colors, labels)`` are: the head of its pickle
    references numpy's ``_reconstruct`` and no tensor (read as bytes, never unpickled)."""
    if path.suffix != ".pth":
        return False
    try:
        with zipfile.ZipFile(path) as z:
            names = [n for n in z.namelist() if n.endswith("/data.pkl")]
            if len(names) != 1:
                return False
            with z.open(names[0]) as f:
                head = f.read(4096)
    except (zipfile.BadZipFile, OSError, KeyError):
        return False
    return b"_reconstruct" in head and b"_rebuild_tensor" not in head


def scene_points_refusal(path: Path) -> str:
    """What to pass instead of a scene's points file (:func:`is_scene_file`)."""
    return (
        f"{path} holds numpy arrays saved with torch.save, as OpenScene's preprocessed "
        "scene points (<scene>.pth, <scene>_vh_clean_2.pth) do: those are no map by "
        "themselves. Pass the scene's fused features, <scene>_<n>.pt, which are read with "
        "these points found beside them (or named with -o points=PATH); see "
        "docs/adapters.md#openscene. A per-image feature map saved this way: "
        "--adapter image-features says how to re-save it."
    )


def scene_id(path: Path) -> str:
    """The scene id of a fused-feature file name."""
    for pattern in (FUSED, NUMPY_FEAT):
        m = pattern.match(path.name)
        if m:
            return m.group("scene")
    return path.stem  # nuScenes: <scene>.pt


def find_points(features: Path) -> Path:
    """The scene's ``.pth`` for a fused-feature file, searched near it.

    Tries ``<scene>.pth`` and ``<scene>_vh_clean_2.pth`` in the file's folder, then one
    and two folders below the folder above it (OpenScene keeps ``data/scannet_3d/val/``
    beside ``data/scannet_multiview_openseg/``).
    """
    sid = scene_id(features)
    names = (f"{sid}.pth", f"{sid}_vh_clean_2.pth")
    hits: list[Path] = []
    for name in names:
        hits += [features.parent / name]
    base = features.parent.parent
    for name in names:
        hits += sorted(base.glob(f"*/{name}")) + sorted(base.glob(f"*/*/{name}"))
    found = list(dict.fromkeys(p for p in hits if p.is_file()))
    if len(found) == 1:
        return found[0]
    if not found:
        raise MapFormatError(
            f"{features}: the scene's points were not found (looked for {names[0]} and "
            f"{names[1]} beside it and under {base}). Pass them with the option "
            "points=PATH (OpenScene's preprocessed .pth, a .ply or a .npy of (N, 3))."
        )
    raise MapFormatError(
        f"{features}: several candidate point files: {', '.join(map(str, found))}. "
        "Choose one with the option points=PATH."
    )


def read_points(path: Path) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """``(coords (N, 3) float32, colors (N, 3) uint8 or None, labels (N,) int64 or None)``.

    From OpenScene's preprocessed ``.pth`` tuple, a ``.ply`` or a ``.npy`` of (N, 3).
    """
    if not path.is_file():
        raise MapFormatError(f"{path}: points file not found. Check the 'points' option.")
    suffix = path.suffix.lower()
    if suffix == ".npy":
        arr = load_npy(path, name="points", what="points file", mmap=False)
        return _coords(arr, path), None, None
    if suffix == ".ply":
        try:
            import open3d as o3d
        except ImportError:
            raise QuashError(
                f'{path}: reading .ply points needs open3d: pip install "quash-plugins[open3d]"'
            ) from None
        pcd = o3d.io.read_point_cloud(str(path))
        coords = _coords(np.asarray(pcd.points), path)
        colors = (
            colors_to_uint8(np.asarray(pcd.colors), str(path), "0-1") if pcd.has_colors() else None
        )
        return coords, colors, None
    obj = load_safe(path, "scene file", numpy_arrays=True)
    if not isinstance(obj, (tuple, list)) or len(obj) not in (2, 3):
        raise MapFormatError(
            f"{path}: expected OpenScene's preprocessed tuple (coords, colors, labels); got "
            f"{type(obj).__name__}{f' of {len(obj)}' if isinstance(obj, (tuple, list)) else ''}."
        )
    coords = _coords(obj[0], path)
    n = len(coords)
    colors = None
    raw = np.asarray(obj[1])
    if raw.ndim == 2:
        if raw.shape != (n, 3):
            raise MapFormatError(
                f"{path}: field 'colors' must be (N, 3) with N = {n}; got {raw.shape}."
            )
        if raw.dtype.kind != "f" or not np.isfinite(raw).all():
            raise MapFormatError(f"{path}: field 'colors' must be finite floats in [-1, 1].")
        colors = pth_colors(raw, path)
    elif raw.ndim != 0:  # nuScenes stores a scalar 0: no colours
        raise MapFormatError(f"{path}: field 'colors' must be (N, 3) or a scalar; got {raw.shape}.")
    labels = None
    if len(obj) == 3:
        lab = check_labels(obj[2], n, str(path), "labels")
        lab[np.isin(lab, IGNORE_LABELS)] = -1
        labels = lab
    return coords, colors, labels


#: Colours this far beyond [-1, 1] are no overshoot of OpenScene's convention but another
#: convention (0-255: up to 255; the limit is the one ``colors_to_uint8`` uses for 0-1).
COLOR_LIMIT = 1.5


def pth_colors(raw: np.ndarray, path: Path) -> np.ndarray:
    """OpenScene's ``.pth`` colours ``(N, 3)`` in [-1, 1] as uint8, ``(c + 1) * 127.5``.

    OpenScene's preprocessing writes ``rgb / 127.5 - 1`` for every dataset, and its data
    loaders take the colours as they are, so a user of OpenScene expects exactly that
    range. Two cases are told apart:

    - values a little outside [-1, 1] (at most :data:`COLOR_LIMIT`: rounding, a
      resampling or augmentation step) are the same convention: they are clipped to the
      nearest colour, with a warning, once per file and process, naming the file, the
      field and how many values were out of range;
    - values beyond that (colours in 0..255, a few hundred) are another convention, and
      clipping them would turn every colour white or black without a word: they are
      refused, naming the file, the field, the range found and the fix. Guessing the
      range instead would hide a preprocessing mistake that OpenScene's own loaders
      would not survive either.
    """
    values = raw.astype(np.float64)
    lo, hi = (float(values.min()), float(values.max())) if values.size else (0.0, 0.0)
    if hi > COLOR_LIMIT or lo < -COLOR_LIMIT:
        looks = (
            "they look like 0-255 colours"
            if lo >= 0 and hi <= 255.5
            else "that is no colour range OpenScene writes"
        )
        raise MapFormatError(
            f"{path}: field 'colors' ranges from {lo:.4g} to {hi:.4g}, not over OpenScene's "
            f"[-1, 1] (rgb / 127.5 - 1, what its preprocessing scripts write); {looks}. "
            "Re-save the .pth with colours / 127.5 - 1 (from 0-255) as OpenScene's "
            "preprocess scripts do, or give the points another way with points=PATH (a "
            ".ply, colours 0-1, or a .npy of coordinates)."
        )
    out = int(np.count_nonzero(np.abs(values) > 1.0 + 1e-6))
    if out and first_time(("openscene-colors", str(path))):
        log.warning(
            "%s: field 'colors' has %d of %d values outside OpenScene's [-1, 1] (from %.4g "
            "to %.4g); they are clipped to the nearest colour",
            path,
            out,
            values.size,
            lo,
            hi,
        )
    return np.clip(np.rint((values + 1.0) * 127.5), 0, 255).astype(np.uint8)


def _coords(arr: Any, path: Path) -> np.ndarray:
    arr = np.asarray(arr)
    if arr.ndim != 2 or arr.shape[1] != 3 or arr.dtype.kind not in "fiu":
        raise MapFormatError(
            f"{path}: field 'coords' must be (N, 3) numbers; got {arr.shape} {arr.dtype}."
            f"{_coords_hint(arr, path)}"
        )
    if arr.dtype.kind == "f" and not np.isfinite(arr).all():
        bad = int(np.argwhere(~np.isfinite(arr))[0][0])
        raise MapFormatError(f"{path}: field 'coords' contains NaN or Inf (first at point {bad}).")
    return arr.astype(np.float32)


def _coords_hint(arr: np.ndarray, path: Path) -> str:
    """The fix for numeric coordinates of the wrong shape: extra columns or transposed."""
    if arr.ndim != 2 or arr.dtype.kind not in "fiu":
        return ""
    if arr.shape[0] == 3:  # before the columns: 3 points with extra columns are rarer
        fix = "arr.T"
        hint = f" It looks transposed, (3, N): save its (N, 3) rows, {fix}"
    elif arr.shape[1] > 3:
        fix = "arr[:, :3]"
        hint = (
            f" It has {arr.shape[1]} columns (xyz + rgb, normals, ...?): if the first 3 are "
            f"x, y, z, save only those, {fix}"
        )
    else:
        return ""
    if path.suffix.lower() == ".npy":
        hint += f" (np.save('{path}', {fix}))"
    return hint + "."
