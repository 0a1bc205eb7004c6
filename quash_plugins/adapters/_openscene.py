"""``openscene``: OpenScene's fused 2D features on the scene's points.

OpenScene (Peng et al., CVPR 2023) projects OpenSeg or LSeg pixel features onto a
scene's points and averages them over the views (``scripts/feature_fusion/*.py``,
``save_fused_feature``). Each scene gets ``<scene_id>_<n>.pt``, written with
``torch.save`` of a dict:

============== =================== ==================================================
``feat``       (M, D) float16      fused features (768 OpenSeg, 512 LSeg), not unit
``mask_full``  (N,) bool           True for the M points that have a feature; row j of
                                   ``feat`` belongs to the j-th True point
============== =================== ==================================================

The points come from the scene's preprocessed ``<scene_id>.pth`` (ScanNet:
``<scene_id>_vh_clean_2.pth``), a pickled tuple of numpy arrays
``(coords (N, 3), colors (N, 3) in [-1, 1], labels (N,))``; labels are class ids with
255 = ignore (ScanNet stores them as float64; nuScenes stores the colours as a scalar 0).
A ``.ply`` (read with open3d) or a ``.npy`` of ``(N, 3)`` coordinates can stand in.

Validation and test splits write one file ``_0`` whose mask covers every visible point;
training splits write several random subsets ``_0`` .. ``_4``: read the one you need.
``<scene>_openscene_feat_<type>.npy`` (per-point features saved by OpenScene's
``--save_feature_as_numpy``, in the ``.pth`` point order) is read the same way, every
point having a feature.

Reading is safe: the ``.pt`` is loaded with ``torch.load(weights_only=True)`` (tensors
only), and the ``.pth`` tuple with ``weights_only=True`` plus an allow-list of exactly
what numpy needs to rebuild arrays (``_reconstruct``, ``ndarray``, ``dtype`` and the
numeric dtype classes). Anything else in the pickle (a class, a function such as
``os.system``) is refused before it runs.
"""

from __future__ import annotations

import logging
import re
import warnings
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import MapFormatError, QuashError
from ..core.interfaces import MapAdapter
from ..core.once import first_time
from ..core.types import LatentMap, record_inputs
from ._npy import load_npy
from ._rows import MaskedRows, colors_to_uint8, scan_finite, should_scan
from ._torch_errors import first_line, is_weights_only_error, weights_only_refusal
from ._vlmaps_common import check_labels, fit_label_names, load_label_names

log = logging.getLogger(__name__)

#: Label values OpenScene ignores: 255 in the preprocessed files, -100 in some loaders.
IGNORE_LABELS = (255, -100)
#: ``<scene>_<n>.pt`` (``save_fused_feature``); the scene id is what precedes ``_<n>``.
FUSED = re.compile(r"^(?P<scene>.+)_(?P<n>\d+)\.pt$")
NUMPY_FEAT = re.compile(r"^(?P<scene>.+)_openscene_feat_(?P<kind>[A-Za-z0-9]+)\.npy$")


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


class OpenSceneAdapter(MapAdapter):
    """Read OpenScene's fused features (``<scene>_<n>.pt``) with the scene's points.

    Parameters
    ----------
    points
        The scene's points: OpenScene's preprocessed ``.pth`` tuple, a ``.ply`` or a
        ``.npy`` of ``(N, 3)`` coordinates. Default: ``<scene>.pth`` or
        ``<scene>_vh_clean_2.pth`` found near the feature file (see :func:`find_points`).
    label_names
        Names of the ``.pth`` labels' class ids, in id order: a file (``.txt``, one name
        per line; ``.yaml``/``.json`` list or ``{id: name}``) or the list itself. OpenScene
        keeps its label lists in code, so give the one your preprocessing used (ScanNet:
        its 20 benchmark classes). Labels 255 (ignore) become -1 (unlabelled).
    all_points
        True (default): every point of the scene is an item, and points without a fused
        feature are zero rows that never match (OpenScene's evaluation counts them too).
        False: only the points with a feature.
    check_finite
        Scan the features for NaN/Inf while reading: True, False or ``"auto"`` (up to
        ``finite_check_mb``).
    finite_check_mb
        Size limit of the ``"auto"`` scan, MiB.

    Examples
    --------
    >>> import tempfile
    >>> adapter = OpenSceneAdapter()
    >>> lmap = adapter.read(adapter.write_example(tempfile.mkdtemp()))
    >>> lmap.kind, lmap.n, lmap.dim, str(lmap.dtype)
    ('points', 120, 16, 'float16')
    """

    name = "openscene"
    priority = 45  # above image-features, which takes any .pt
    file_names = ("*_[0-9]*.pt", "*_openscene_feat_*.npy")

    def __init__(
        self,
        points: str | Path | None = None,
        label_names: Any = None,
        all_points: bool = True,
        check_finite: bool | str = "auto",
        finite_check_mb: float = 512.0,
    ) -> None:
        self.points = points
        self.label_names = label_names
        self.all_points = all_points
        self.check_finite = check_finite
        self.finite_check_mb = finite_check_mb

    def sniff(self, source: Any) -> bool:
        try:
            if not isinstance(source, (str, Path)):
                return False
            p = Path(source)
            if not p.is_file():
                return False
            if p.suffix == ".npy":
                return NUMPY_FEAT.match(p.name) is not None
            return p.suffix == ".pt" and is_fused_file(p)
        except OSError:
            return False

    def unrecognised_hint(self, source: Any) -> str:
        """For OpenScene's scene points passed as the map: pass the fused features."""
        try:
            path = Path(source).expanduser() if isinstance(source, (str, Path)) else None
            return scene_points_refusal(path) if path and is_scene_file(path) else ""
        except OSError:
            return ""

    def read(self, source: Any, **options: Any) -> LatentMap:
        opts = self.options(options)
        path = Path(source).expanduser()
        if not path.is_file():
            raise MapFormatError(
                f"{path}: not a file. Pass OpenScene's fused features <scene>_<n>.pt (or a "
                "<scene>_openscene_feat_<type>.npy)."
            )
        if path.suffix == ".npy":
            feat, mask = self._read_numpy_features(path)
        elif is_scene_file(path):
            raise MapFormatError(scene_points_refusal(path))
        else:
            feat, mask = self._read_fused(path)
        points_path = Path(opts["points"]).expanduser() if opts["points"] else find_points(path)
        coords, colors, labels = read_points(points_path)
        n = len(coords)
        if len(mask) != n:
            # a .npy of per-point features has no mask_full: its rows are the points
            field = (
                f"field 'feat' has {len(mask)} rows (one per point)"
                if path.suffix == ".npy"
                else f"field 'mask_full' has {len(mask)} entries"
            )
            raise MapFormatError(
                f"{path}: {field} but {points_path} has {n} points; the features belong to "
                "another scene or preprocessing: pass that scene's points with the option "
                "points=PATH."
            )
        m, d = int(feat.shape[0]), int(feat.shape[1])
        if should_scan(opts["check_finite"], m * d * feat.dtype.itemsize, opts["finite_check_mb"]):
            scan_finite(feat, str(path), "feat")
        if opts["all_points"]:
            # every point an item; a scene whose points all have a feature reads the
            # table itself
            embeddings: Any = feat if bool(np.all(mask)) else MaskedRows(feat, mask)
            keep = slice(None)
        else:
            embeddings = feat
            keep = mask
        names = load_label_names(opts["label_names"])
        kept_labels = labels[keep] if labels is not None else None
        names = fit_label_names(names, kept_labels, opts["label_names"], points_path)
        hint = {768: "openseg ViT-L/14@336 768", 512: "lseg CLIP ViT-B/32 512"}.get(
            d, f"{d}-d features"
        )
        return LatentMap(
            embeddings=embeddings,
            kind="points",
            positions=coords[keep],
            colors=colors[keep] if colors is not None else None,
            labels=kept_labels,
            label_names=names,
            normalize=True,
            source=record_inputs(
                {
                    "adapter": self.name,
                    "path": str(path),
                    "points": str(points_path),
                    "scene": scene_id(path),
                    "featured_points": m,
                    "scene_points": n,
                    "encoder_hint": hint,
                },
                points_path,
                opts["label_names"],  # a file of names (a list in memory is no input)
            ),
        )

    @staticmethod
    def _read_fused(path: Path) -> tuple[np.ndarray, np.ndarray]:
        obj = load_safe(path, "fused-feature file")
        torch = _torch()
        if not isinstance(obj, dict) or "feat" not in obj or "mask_full" not in obj:
            raise _fused_keys_error(path, obj)
        feat, mask = obj["feat"], obj["mask_full"]
        if not isinstance(feat, torch.Tensor) or feat.ndim != 2 or not feat.is_floating_point():
            raise MapFormatError(
                f"{path}: field 'feat' must be a float tensor (M, D); got "
                f"{getattr(feat, 'shape', type(feat).__name__)}."
            )
        mask = mask.numpy() if isinstance(mask, torch.Tensor) else np.asarray(mask)
        mask = _check_mask(mask, path)
        if feat.dtype == torch.bfloat16:
            feat = feat.float()
        feat_np = feat.detach().numpy()
        if int(mask.sum()) != feat_np.shape[0]:
            raise MapFormatError(
                f"{path}: field 'feat' has {feat_np.shape[0]} rows but 'mask_full' marks "
                f"{int(mask.sum())} points; each True point needs one row."
            )
        if feat_np.shape[1] == 0:
            raise MapFormatError(f"{path}: field 'feat' has no feature dimension.")
        return _mapped(path, feat_np, mask)

    @staticmethod
    def _read_numpy_features(path: Path) -> tuple[np.ndarray, np.ndarray]:
        feat = load_npy(path)
        if feat.ndim != 2 or feat.shape[1] == 0 or feat.dtype.kind != "f":
            raise MapFormatError(
                f"{path}: per-point features must be a float array (N, D); got "
                f"{feat.shape} {feat.dtype}."
            )
        return feat, np.ones(feat.shape[0], dtype=bool)

    def write_example(self, directory: Path) -> Path:
        """A small ScanNet-style scene: ``scannet_3d/val/<scene>_vh_clean_2.pth`` and
        ``openseg/<scene>_0.pt``, written the way OpenScene's scripts write them."""
        torch = _torch()
        rng = np.random.default_rng(0)
        root = Path(directory)
        n, d = 120, 16
        coords = rng.uniform(-2, 2, size=(n, 3))
        colors = rng.integers(0, 256, size=(n, 3)) / 127.5 - 1
        labels = rng.integers(0, 4, size=n).astype(np.float64)
        labels[::9] = 255
        pth = root / "scannet_3d" / "val" / "scene0000_00_vh_clean_2.pth"
        pth.parent.mkdir(parents=True, exist_ok=True)
        torch.save((coords, colors, labels), pth)
        mask = torch.from_numpy(rng.random(n) < 0.8)
        feat = torch.from_numpy(rng.normal(size=(int(mask.sum()), d))).half()
        pt = root / "openseg" / "scene0000_00_0.pt"
        pt.parent.mkdir(parents=True, exist_ok=True)
        torch.save({"feat": feat, "mask_full": mask}, pt)
        return pt


def _fused_keys_error(path: Path, obj: Any) -> MapFormatError:
    """The refusal of a ``.pt`` that lacks ``feat`` or ``mask_full``: what is missing, what
    the file holds, and what to write instead."""
    layout = (
        "OpenScene's fusion scripts (save_fused_feature) write {'feat': (M, D) float16, "
        "'mask_full': (N,) bool}, row j of 'feat' being the j-th True point"
    )
    if not isinstance(obj, dict):
        return MapFormatError(
            f"{path}: expected OpenScene's dict with fields 'feat' and 'mask_full'; got a "
            f"{type(obj).__name__}. {layout}. Features of every point, in the scene's point "
            "order, can be saved with np.save as <scene>_openscene_feat_<type>.npy instead."
        )
    missing = [k for k in ("feat", "mask_full") if k not in obj]
    keys = ", ".join(repr(k) for k in sorted(map(str, obj))) or "none"
    fix = (
        "if 'feat' has a row for every point of the scene, in its point order, add "
        "'mask_full' all True, or save 'feat' with np.save as "
        "<scene>_openscene_feat_<type>.npy"
        if missing == ["mask_full"]
        else "re-save the file with both fields"
    )
    return MapFormatError(
        f"{path}: field {' and '.join(repr(k) for k in missing)} missing (the dict holds "
        f"{keys}). {layout}: {fix}."
    )


def _mapped(path: Path, feat: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``feat`` and ``mask`` as memory maps of the ``.pt`` file itself where it stores
    them as plain arrays (see :mod:`._torch_zip`), else as loaded.

    A memory-mapped table pickles as its file, offset, shape and dtype, so a Dask task
    reopens it on the worker instead of carrying the table in the task graph.
    """
    from ._torch_zip import tensor_memmaps

    maps = tensor_memmaps(path)
    table, flags = maps.get("feat"), maps.get("mask_full")
    if table is not None and table.shape == feat.shape and table.dtype == feat.dtype:
        feat = table
    if flags is not None and flags.shape == mask.shape and flags.dtype == mask.dtype:
        mask = flags
    return feat, mask


def _check_mask(mask: np.ndarray, path: Path) -> np.ndarray:
    if mask.ndim != 1:
        raise MapFormatError(f"{path}: field 'mask_full' must be 1-D (N,); got {mask.shape}.")
    if mask.dtype != bool:
        if mask.dtype.kind not in "iu" or (mask.size and not np.isin(mask, (0, 1)).all()):
            raise MapFormatError(
                f"{path}: field 'mask_full' must be bool; got {mask.dtype}.{_indices_hint(mask)}"
            )
        mask = mask.astype(bool)
    return mask


def _indices_hint(mask: np.ndarray) -> str:
    """The fix for a ``mask_full`` of point indices: OpenScene's is a bool mask."""
    if mask.dtype.kind not in "iu" or not mask.size or int(mask.min()) < 0:
        return ""
    return (
        f" Its {mask.size} values (0 to {int(mask.max())}) look like the indices of the "
        "featured points; OpenScene saves a bool mask over all the scene's points, True "
        "where 'feat' has a row, row j being the j-th True point. Build it and save the .pt "
        "again: m = np.zeros(n_points, bool); m[idx] = True (n_points: the scene's point "
        "count), with 'feat' as feat[np.argsort(idx)] if idx is not sorted."
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
