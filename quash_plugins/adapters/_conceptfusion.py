"""``conceptfusion``: ConceptFusion maps as gradslam's ``PointClouds.save_to_h5`` writes them.

A saved map is a directory ``<dir_to_save_map>/pointclouds/`` holding one HDF5 file per
attribute, each with a single dataset named after the file (no groups, no compression):

=====================  ==================  ===============================================
file                   dataset             content
=====================  ==================  ===============================================
``pc_points.h5``       ``pc_points``       ``(N, 3)`` float32, metres (required)
``pc_embeddings.h5``   ``pc_embeddings``   ``(N, D)`` float16/float32, not normalised,
                                           zero rows where nothing was fused (required)
``pc_colors.h5``       ``pc_colors``       ``(N, 3)`` float, 0-255
``pc_features.h5``     ``pc_features``     ``(N, C)`` gradslam features (checked, unused)
``pc_confidences.h5``  ``pc_confidences``  ``(N,)`` or ``(N, 1)`` (checked, unused)
=====================  ==================  ===============================================

The embeddings stay on disk, an :class:`~quash_plugins.core.h5rows.H5Rows` view that
opens ``pc_embeddings.h5`` read-only for each block it reads (no file is held open, so
no HDF5 lock either): nothing is copied and float16 stays float16 until a block is
used. Rows are L2-normalised block by block (``normalize=True``); zero rows are
unobserved and never match.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import MapFormatError, QuashError
from ..core.h5rows import H5Rows, open_h5_read
from ..core.interfaces import MapAdapter
from ..core.types import LatentMap, record_inputs
from ._rows import colors_to_uint8, scan_finite, should_scan

log = logging.getLogger(__name__)

REQUIRED = ("pc_points", "pc_embeddings")
OPTIONAL = ("pc_colors", "pc_features", "pc_confidences")


def _h5py():
    try:
        import h5py
    except ImportError:  # pragma: no cover - h5py is installed in dev
        raise QuashError(
            'Reading ConceptFusion maps needs h5py: pip install "quash-plugins[hdf5]"'
        ) from None
    return h5py


def find_pointclouds_dir(source: Any) -> Path | None:
    """The ``pointclouds/`` directory for ``source`` (that directory, its parent or a file in it)."""
    if not isinstance(source, (str, Path)):
        return None
    p = Path(source).expanduser()
    if p.is_file() and p.suffix == ".h5" and p.stem.startswith("pc_"):
        p = p.parent
    if not p.is_dir():
        return None
    for cand in (p, p / "pointclouds"):
        if (cand / "pc_points.h5").is_file() or (cand / "pc_embeddings.h5").is_file():
            return cand
    return None


def open_dataset(path: Path, name: str):
    """Open ``path`` read-only and return its dataset ``name``; clear errors otherwise."""
    h5py = _h5py()
    try:
        f = open_h5_read(path)
    except OSError as exc:
        raise MapFormatError(
            f"{path}: not a readable HDF5 file ({exc}). The file may be truncated or corrupt; "
            "re-save the map."
        ) from None
    if name not in f:
        found = ", ".join(sorted(f.keys())) or "nothing"
        raise MapFormatError(
            f"{path}: missing dataset {name!r} (gradslam names each dataset after its file). "
            f"Found: {found}."
        )
    ds = f[name]
    if not isinstance(ds, h5py.Dataset):
        f.close()
        raise MapFormatError(f"{path}: {name!r} is a group, not a dataset.")
    return ds


class ConceptFusionAdapter(MapAdapter):
    """Read a ConceptFusion / gradslam ``pointclouds/`` directory.

    Parameters
    ----------
    color_range
        Range of ``pc_colors``: ``"0-255"`` (gradslam's, default), ``"0-1"`` or ``"auto"``.
    check_finite
        Scan the embeddings for NaN/Inf while reading: True, False or ``"auto"`` (only when
        they take at most ``finite_check_mb``; larger maps are checked block by block at
        query time instead).
    finite_check_mb
        Size limit of the ``"auto"`` scan, in MiB.

    Examples
    --------
    >>> from quash_plugins import registry
    >>> lmap = registry.create("adapters", "conceptfusion").read("saved-map")  # doctest: +SKIP
    >>> lmap.embeddings.dtype  # doctest: +SKIP
    dtype('float16')
    """

    name = "conceptfusion"
    priority = 40

    def __init__(
        self,
        color_range: str = "0-255",
        check_finite: bool | str = "auto",
        finite_check_mb: float = 512.0,
    ) -> None:
        self.color_range = color_range
        self.check_finite = check_finite
        self.finite_check_mb = finite_check_mb

    def sniff(self, source: Any) -> bool:
        try:
            return find_pointclouds_dir(source) is not None
        except OSError:
            return False

    def read(self, source: Any, **options: Any) -> LatentMap:
        opts = self.options(options)
        folder = find_pointclouds_dir(source)
        if folder is None:
            raise MapFormatError(
                f"{source}: no ConceptFusion map here. Expected a 'pointclouds/' directory (or "
                "its parent) holding pc_points.h5 and pc_embeddings.h5."
            )
        files = {key: folder / f"{key}.h5" for key in (*REQUIRED, *OPTIONAL)}
        for key in REQUIRED:
            if not files[key].is_file():
                raise MapFormatError(
                    f"{files[key]}: missing file; a ConceptFusion map needs "
                    "pc_points.h5 and pc_embeddings.h5."
                )

        opened: list[Any] = []  # every file is closed once read: no lock is held

        def dataset(path: Path, name: str) -> Any:
            ds = open_dataset(path, name)
            opened.append(ds.file)
            return ds

        try:
            points_ds = dataset(files["pc_points"], "pc_points")
            label_pts = f"{files['pc_points']} (dataset 'pc_points')"
            if points_ds.ndim != 2 or points_ds.shape[1] != 3:
                raise MapFormatError(
                    f"{label_pts}: field 'positions' must be (N, 3); got shape "
                    f"{points_ds.shape}.{_batch_hint(points_ds.shape, 'points')}"
                )
            if points_ds.dtype.kind not in "fiu":
                raise MapFormatError(
                    f"{label_pts}: field 'positions' must hold numbers (metres); got "
                    f"{points_ds.dtype}. Re-save the points as float32."
                )
            n = int(points_ds.shape[0])

            emb = dataset(files["pc_embeddings"], "pc_embeddings")
            label_emb = f"{files['pc_embeddings']} (dataset 'pc_embeddings')"
            if emb.ndim != 2:
                raise MapFormatError(
                    f"{label_emb}: field 'embeddings' must be 2-D (N, D); got shape {emb.shape}."
                    f"{_batch_hint(emb.shape, 'embeddings')}"
                )
            if emb.shape[1] == 0:
                raise MapFormatError(
                    f"{label_emb}: field 'embeddings' has no feature dimension (shape {emb.shape})."
                )
            if emb.dtype.kind not in "fiu":
                raise MapFormatError(
                    f"{label_emb}: field 'embeddings' must hold numbers; got {emb.dtype}."
                )
            if emb.shape[0] != n:
                raise MapFormatError(
                    _row_mismatch(label_emb, "embeddings", emb.shape[0], n, files["pc_points"])
                )

            positions = np.asarray(points_ds[()], dtype=np.float32)
            if not np.isfinite(positions).all():
                bad = int(np.argwhere(~np.isfinite(positions))[0][0])
                raise MapFormatError(
                    f"{label_pts}: field 'positions' contains NaN or Inf (first at row {bad})."
                )

            colors = None
            if files["pc_colors"].is_file():
                cds = dataset(files["pc_colors"], "pc_colors")
                label = f"{files['pc_colors']} (dataset 'pc_colors')"
                if cds.ndim == 2 and cds.shape[1] == 3 and cds.shape[0] != n:
                    raise MapFormatError(
                        _row_mismatch(label, "colors", cds.shape[0], n, files["pc_points"])
                    )
                if cds.shape != (n, 3):
                    raise MapFormatError(
                        f"{label}: field 'colors' must be (N, 3) with N = {n}; got shape {cds.shape}."
                    )
                colors = colors_to_uint8(cds[()], label, opts["color_range"])

            extra: dict[str, Any] = {}
            for key in ("pc_features", "pc_confidences"):
                if files[key].is_file():
                    ds = dataset(files[key], key)
                    if ds.ndim == 0 or ds.shape[0] != n:
                        raise MapFormatError(
                            _row_mismatch(
                                f"{files[key]} (dataset {key!r})",
                                key,
                                ds.shape[0] if ds.ndim else 0,
                                n,
                                files["pc_points"],
                            )
                        )
                    extra[f"{key}_file"] = str(files[key])

            if should_scan(
                opts["check_finite"], emb.size * emb.dtype.itemsize, opts["finite_check_mb"]
            ):
                scan_finite(emb, label_emb, "embeddings")

            log.debug(
                "conceptfusion: %d points x %d (%s) from %s", n, emb.shape[1], emb.dtype, folder
            )
            return LatentMap(
                embeddings=H5Rows.from_dataset(emb),
                kind="points",
                positions=positions,
                colors=colors,
                normalize=True,
                source=record_inputs(  # the folder: every file read is in it
                    {
                        "adapter": self.name,
                        "path": str(folder),
                        "embeddings_file": str(files["pc_embeddings"]),
                        **extra,
                    }
                ),
            )
        finally:
            for f in opened:
                f.close()

    def write_example(self, directory: Path) -> Path:
        """Write a small gradslam-style ``saved-map/pointclouds/`` and return ``saved-map``."""
        rng = np.random.default_rng(0)
        n, d = 60, 16
        emb = rng.normal(size=(n, d)).astype(np.float16) * 3
        emb[::7] = 0
        arrays = {
            "pc_points": rng.uniform(-2, 2, size=(n, 3)).astype(np.float32),
            "pc_colors": rng.uniform(0, 255, size=(n, 3)).astype(np.float32),
            "pc_embeddings": emb,
            "pc_features": rng.normal(size=(n, 4)).astype(np.float32),
            "pc_confidences": rng.uniform(size=(n, 1)).astype(np.float32),
        }
        root = Path(directory) / "saved-map"
        write_pointclouds(root, arrays)
        return root


def write_pointclouds(root: str | Path, arrays: dict[str, np.ndarray]) -> Path:
    """Write ``arrays`` (keys ``pc_points``, ...) as gradslam does: ``root/pointclouds/<key>.h5``."""
    h5py = _h5py()
    folder = Path(root) / "pointclouds"
    folder.mkdir(parents=True, exist_ok=True)
    for key, value in arrays.items():
        with h5py.File(folder / f"{key}.h5", "w") as f:
            f.create_dataset(key, data=np.asarray(value))
    return folder


def _row_mismatch(label: str, field: str, rows: int, n: int, points_file: Path) -> str:
    """The error for a per-point file whose row count is not ``pc_points``'s, with the fix."""
    return (
        f"{label}: field {field!r} has {rows} rows, but {points_file} has {n} points; every "
        "per-point file needs one row per point. The file may be from another map (copy the "
        "whole pointclouds/ folder of one map again), or the map was saved part-way: re-save "
        "it (gradslam's Pointclouds.save_to_h5) so that all its files are written together."
    )


def _batch_hint(shape: tuple[int, ...], name: str) -> str:
    """The fix for a gradslam padded batch of one cloud, ``(1, N, ...)``, else ''."""
    if len(shape) == 3 and shape[0] == 1:
        return (
            f" It is a batch of one cloud (gradslam's padded {name}, shape (1, N, ...)): "
            f"save {name}[0] (the cloud's own (N, ...) rows) instead."
        )
    return ""
