"""The files of the ``image-features`` adapter: one frame's feature file and RGB image.

Loading a frame (a bare tensor with ``torch.load(weights_only=True, mmap=True)``, or a
``.npy`` memory-mapped), its layout (``(H, W, D)`` or ``(1, D, h, w)``), the folder's
frame files in natural order, the image with a frame's stem, and the checks that turn
a folder's mistakes (two files of one stem, an images-only folder, an ``images=`` folder
no frame matches) into errors that name the file and the fix.
"""

from __future__ import annotations

import logging
import re
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import MapFormatError, QuashError
from ._npy import load_npy
from ._torch_errors import first_line, is_weights_only_error, weights_only_refusal

log = logging.getLogger(__name__)

FEATURE_SUFFIXES = (".pt", ".pth", ".npy")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".PNG", ".JPG", ".JPEG")
#: Sibling folders searched for RGB frames (relative to the feature directory's parent).
IMAGE_DIRS = ("rgb", "color", "colors", "image", "images", "results", "frames")
#: Files that belong to other layouts (VLMaps 2D grids, OpenLex3D) and are never frames.
NOT_FRAMES = re.compile(r"^(grid_|weight_|color_top_down|obstacles|embeddings$|index$)")
#: Camera and trajectory files that sit beside per-frame features (``poses.npy``,
#: ``intrinsics.npy``, ``cam_poses.npy``, ``pose_000010.npy``, ``K.npy``): never frames.
SIDE_FILES = re.compile(
    r"^((cam(era)?[_-]?)?(poses?|intrinsics?|extrinsics?|traj(ectory)?|timestamps?)([_-].*)?"
    r"|k|calib(ration)?)$",
    re.IGNORECASE,
)
LAYOUTS = ("auto", "hwd", "1dhw")


def _natural_key(name: str) -> list[Any]:
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", name)]


def import_torch():
    try:
        import torch
    except ImportError:
        raise QuashError(
            'Reading .pt feature maps needs torch: pip install "quash-plugins[clip]"'
        ) from None
    return torch


def _load_tensor(path: Path) -> np.ndarray:
    """A bare tensor saved with ``torch.save``, as numpy (memory-mapped where possible)."""
    torch = import_torch()
    try:
        try:
            obj = torch.load(path, map_location="cpu", weights_only=True, mmap=True)
        except RuntimeError as exc:  # legacy (non-zip) files cannot be memory-mapped
            if "mmap" not in str(exc):
                raise
            obj = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - torch raises many types for bad files
        if is_weights_only_error(exc):
            raise weights_only_refusal(
                exc,
                path,
                "feature file",
                "Re-save the frame as a bare tensor where it was written, "
                f"torch.save(torch.as_tensor(features), '{path.name}'), or as numpy, which "
                f"this adapter reads too: np.save('{path.stem}.npy', features).",
            ) from None
        msg = first_line(exc)
        if "maximum supported version" in msg:  # torch's own words for a newer archive
            raise MapFormatError(
                f"{path}: written by a newer torch than this one ({torch.__version__}): "
                f"{msg} Upgrade torch here, or re-save each frame where it was written as "
                f"numpy, which this adapter reads too: np.save('{path.stem}.npy', "
                "t.cpu().numpy())."
            ) from None
        raise MapFormatError(
            f"{path}: not a readable tensor file ({msg}). Only bare tensors saved with "
            "torch.save are read, with weights_only=True (no pickled objects). A damaged "
            "or truncated file (an interrupted copy): copy or extract that frame again."
        ) from None
    if not isinstance(obj, torch.Tensor):
        raise MapFormatError(
            f"{path}: holds a {type(obj).__name__}, not a bare tensor (H, W, D) or (1, D, h, w)"
            f"{_not_a_tensor_fix(obj, path)}"
        )
    obj = obj.detach()
    if obj.dtype == torch.bfloat16:
        obj = obj.float()
    return obj.numpy()


def _not_a_tensor_fix(obj: Any, path: Path) -> str:
    """How to turn what a ``.pt`` holds into the bare tensor this adapter reads."""
    if not isinstance(obj, dict):
        return ". Save one frame's feature tensor per file: torch.save(tensor, PATH)."
    keys = list(obj)
    if {"feat", "mask_full"} <= set(keys):
        return (
            " (keys 'feat', 'mask_full': OpenScene's fused point features, not an image's). "
            "Read it with --adapter openscene (docs/adapters.md#openscene)."
        )
    shown = ", ".join(repr(k) for k in keys[:8]) + (", ..." if len(keys) > 8 else "")
    key = next((k for k in keys if isinstance(obj[k], import_torch().Tensor)), "KEY")
    return (
        f" (keys: {shown}). Save the feature tensor itself, one file per frame: "
        f"torch.save(d[{key!r}], {str(path.name)!r})."
    )


def load_array(path: Path) -> np.ndarray:
    if path.suffix == ".npy":
        return load_npy(path, what="frame")
    return _load_tensor(path)


def frame_layout(shape: tuple[int, ...], layout: str, path: Path) -> tuple[int, int, int, str]:
    """``(H, W, D, layout)`` of one feature file; wrong ranks raise naming the file."""
    if layout not in LAYOUTS:
        raise MapFormatError(f"layout must be one of {LAYOUTS}; got {layout!r}.")
    if layout == "auto":
        if len(shape) == 4 and shape[0] == 1:
            layout = "1dhw"
        elif len(shape) == 3:
            layout = "hwd"
        else:
            raise MapFormatError(
                f"{path}: field 'embeddings' must be (H, W, D) or (1, D, h, w); got shape "
                f"{tuple(shape)} (rank {len(shape)})."
            )
    if layout == "1dhw":
        if len(shape) != 4 or shape[0] != 1:
            raise MapFormatError(_layout_refusal(path, shape, layout))
        _, d, h, w = shape
    else:
        if len(shape) != 3:
            raise MapFormatError(_layout_refusal(path, shape, layout))
        h, w, d = shape
    if min(h, w, d) <= 0:
        raise MapFormatError(f"{path}: field 'embeddings' is empty (shape {tuple(shape)}).")
    return int(h), int(w), int(d), layout


def _layout_refusal(path: Path, shape: tuple[int, ...], layout: str) -> str:
    """The option ``layout`` names a shape the frame does not have: the field, the
    option and the fix (the layout the frame has, or ``auto``)."""
    wanted = "(1, D, h, w)" if layout == "1dhw" else "(H, W, D)"
    fits = "hwd" if len(shape) == 3 else "1dhw" if len(shape) == 4 and shape[0] == 1 else None
    fix = (
        f"this frame is read with layout={fits} (or layout=auto, the default, which "
        "reads each frame by its rank)"
        if fits
        else "save each frame as (H, W, D) or (1, D, h, w)"
    )
    return (
        f"{path}: field 'embeddings' has shape {tuple(shape)}, not the {wanted} of the "
        f"option layout={layout}; {fix}."
    )


def as_rows(arr: np.ndarray, layout: str) -> np.ndarray:
    """``(H*W, D)`` view of one frame (a transposed view for the (1, D, h, w) layout)."""
    if layout == "1dhw":
        d = arr.shape[1]
        return arr[0].reshape(d, -1).T
    return arr.reshape(-1, arr.shape[-1])


def not_a_frame_name(stem: str) -> bool:
    """True for a file stem that names no frame: another layout's file
    (:data:`NOT_FRAMES`) or a camera/trajectory file (:data:`SIDE_FILES`)."""
    return bool(NOT_FRAMES.match(stem) or SIDE_FILES.match(stem))


def list_feature_files(folder: Path) -> list[Path]:
    """The folder's ``.pt``/``.pth``/``.npy`` files in natural order of their stems,
    other layouts' files (:data:`NOT_FRAMES`) left out; camera files (:data:`SIDE_FILES`)
    are kept for :func:`split_frames` to leave out and report."""
    files = [
        p
        for p in folder.iterdir()
        if p.is_file() and p.suffix in FEATURE_SUFFIXES and not NOT_FRAMES.match(p.stem)
    ]
    return sorted(files, key=lambda p: _natural_key(p.stem))


def _frame_rank(shape: tuple[int, ...], layout: str) -> bool:
    """Whether ``shape`` has a frame's rank under ``layout``."""
    rank3 = len(shape) == 3
    rank4 = len(shape) == 4 and shape[0] == 1
    return {"hwd": rank3, "1dhw": rank4}.get(layout, rank3 or rank4)


def _dims(shape: tuple[int, ...], layout: str) -> tuple[int, ...]:
    """The axes that may be D: the last of ``(H, W, D)``, also the first for a ``(D, h,
    w)`` frame (its own error then says so); axis 1 of ``(1, D, h, w)``."""
    if len(shape) == 4:
        return (shape[1],)
    return (shape[2],) if layout == "hwd" else (shape[2], shape[0])


def split_frames(
    files: list[Path], shapes: dict[Path, tuple[int, ...]], layout: str
) -> tuple[list[Path], list[str]]:
    """``(frames, skipped)``: the files of a feature folder that are frames, and a note
    for each one that is plainly not a frame feature map: a camera file by its name
    (``poses.npy``, ``intrinsics.npy``), or a ``.npy`` whose shape is no frame's (a
    ``(4, 4)`` pose, ``(3, 3)`` intrinsics), or whose D is not the one most frames have
    (``(N, 4, 4)`` poses beside ``(H, W, 512)`` frames). ``shapes`` holds the ``.npy``
    headers and the shapes of loaded tensors.

    A ``.pt`` is never left out by its shape (its error names it), nor a ``.npy`` when
    no frame would be left, or when no D is held by more frames than the file's own
    (two frames of two models): the usual error then names the file.
    """
    skipped: list[str] = []
    named = [f for f in files if SIDE_FILES.match(f.stem)]
    skipped += [f"{f.name} (a camera file, by its name)" for f in named]
    rest = [f for f in files if f not in named]
    npy = [f for f in rest if f.suffix == ".npy"]
    odd = [f for f in npy if not _frame_rank(shapes[f], layout)]
    kept = [f for f in rest if f not in odd]
    if not kept:  # nothing would be read: its own error names the file
        return rest, skipped
    skipped += [f"{f.name} (shape {shapes[f]}, not (H, W, D) or (1, D, h, w))" for f in odd]
    counts: dict[int, int] = {}
    for f in kept:
        if _frame_rank(shapes[f], layout):  # a .pt of another rank: its error names it
            d = _dims(shapes[f], layout)[0]
            counts[d] = counts.get(d, 0) + 1
    if not counts:
        return kept, skipped
    dim = max(counts, key=lambda d: counts[d])
    others = [f for f in kept if f.suffix == ".npy" and dim not in _dims(shapes[f], layout)]
    if others and all(counts[dim] > counts[_dims(shapes[f], layout)[0]] for f in others):
        kept = [f for f in kept if f not in others]
        skipped += [
            f"{f.name} (shape {shapes[f]}: D {_dims(shapes[f], layout)[0]}, not the frames' {dim})"
            for f in others
        ]
    return kept, skipped


def check_options(opts: dict[str, Any]) -> None:
    """``colors`` and ``cache_frames`` are honoured as given or refused, never coerced."""
    if not isinstance(opts["colors"], (bool, np.bool_)):
        raise MapFormatError(
            f"Adapter 'image-features': option 'colors' must be true or false; got "
            f"{opts['colors']!r}."
        )
    cache = opts["cache_frames"]
    if isinstance(cache, (bool, np.bool_)) or not isinstance(cache, (int, np.integer)) or cache < 1:
        raise MapFormatError(
            "Adapter 'image-features': option 'cache_frames' must be a whole number of "
            f"frames, at least 1; got {cache!r}."
        )


def refuse_shared_stems(files: list[Path]) -> None:
    """Two files of one stem would be two frames with one id (``masks_per_frame`` keys)."""
    seen: dict[str, Path] = {}
    for f in files:
        if f.stem in seen:
            raise MapFormatError(
                f"{f.parent}: frame {f.stem!r} has two feature files, {seen[f.stem].name} and "
                f"{f.name}; a frame is one file named after its image. Move one of them "
                "out of the folder."
            )
        seen[f.stem] = f


def refuse_unmatched_images(images: str, files: list[Path]) -> None:
    """``images=DIR`` was given, but no frame has an image there: the option is not
    honoured, so it is refused rather than the map read without colours."""
    found = sorted(
        p.name for p in Path(images).expanduser().iterdir() if p.suffix in IMAGE_SUFFIXES
    )
    holds = (
        f"it holds {', '.join(found[:3])}{', ...' if len(found) > 3 else ''}"
        if found
        else ("it holds no .png or .jpg")
    )
    raise MapFormatError(
        f"images={images!r}: no image named after a frame ({files[0].stem}.png, "
        f"{files[0].stem}.jpg...); {holds}. An image must have its feature file's stem: "
        "rename them, or pass colors=false to read the map without colours."
    )


def images_only_hint(path: Path) -> str:
    """Said when a folder without features holds images: the RGB folder was given."""
    if not path.is_dir() or not any(p.suffix in IMAGE_SUFFIXES for p in path.iterdir()):
        return ""
    return (
        " It holds images: pass the folder of their feature files (ConceptFusion's "
        "saved-feat/); the images are found beside it, or name them with -o images=DIR."
    )


def find_image(stem: str, dirs: list[Path]) -> Path | None:
    for d in dirs:
        for suffix in IMAGE_SUFFIXES:
            p = d / f"{stem}{suffix}"
            if p.is_file():
                return p
    return None


def read_rgb(
    path: Path, height: int, width: int, turned: list[str] | None = None
) -> np.ndarray | None:
    """``(H, W, 3)`` uint8, resized (bilinear) to the feature resolution when it differs.

    An image whose orientation is not the feature map's (landscape for a portrait frame,
    or the reverse) is resized all the same, and described in ``turned``: its frame was
    likely saved ``(W, H, D)``, and its colours and masks would not line up."""
    try:
        from PIL import Image
    except ImportError:  # pragma: no cover - pillow ships with matplotlib
        log.warning("Pillow is not installed; colours are not read from %s", path)
        return None
    try:
        with Image.open(path) as im:
            im = im.convert("RGB")
            w, h = im.size
            if turned is not None and (w - h) * (width - height) < 0:
                turned.append(f"{path.name} {w} x {h} for features {width} x {height}")
            if im.size != (width, height):
                im = im.resize((width, height), Image.Resampling.BILINEAR)
            return np.asarray(im, dtype=np.uint8)
    except OSError as exc:
        log.warning("cannot read image %s (%s); using grey", path, exc)
        return None
