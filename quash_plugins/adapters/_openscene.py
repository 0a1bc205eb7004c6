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
``os.system``) is refused before it runs (:mod:`._torch_load`). Which file is which
(read as bytes, never unpickled), finding the scene's points and reading them:
:mod:`._openscene_files`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import MapFormatError
from ..core.interfaces import MapAdapter
from ..core.types import LatentMap, record_inputs
from ._npy import load_npy
from ._openscene_files import (
    NUMPY_FEAT,
    find_points,
    is_fused_file,
    is_scene_file,
    read_points,
    scene_id,
    scene_points_refusal,
)
from ._rows import MaskedRows, scan_finite, should_scan
from ._torch_load import _torch, load_safe
from ._torch_load import numpy_allow_list as numpy_allow_list  # importable from here too
from ._vlmaps_common import fit_label_names, load_label_names


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
