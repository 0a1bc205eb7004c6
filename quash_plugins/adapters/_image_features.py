"""``image-features``: per-image feature maps, one file per frame.

ConceptFusion's ``extract_conceptfusion_features.py`` saves ``saved-feat/<stem>.pt``: a
bare tensor ``(H, W, D)`` float16 whose pixels are unit vectors, zero where no mask
covered them. Its LSeg/DINO extractors save ``(1, D, h, w)`` float32. ``<stem>.npy`` files
in either layout are read too. ``<stem>`` is the stem of the RGB frame the features came
from.

The map is a pixel map: item ``offset + y * W + x`` is pixel ``(x, y)`` of a frame, frames
in natural order of their stems (``frame2`` before ``frame10``). ``LatentMap.frames``
records each frame's id (the stem), H, W, offset and RGB image, and
:func:`~quash_plugins.adapters.masks_per_frame` turns a result mask back into one ``(H, W)`` mask per image.

Design choices
--------------
- Embeddings are a :class:`~quash_plugins.adapters._rows.ConcatRows`: frames are loaded
  (``torch.load(weights_only=True, mmap=True)``, ``np.load(mmap_mode="r")``) when their
  rows are read, a few at a time; nothing is concatenated into one copy.
- ``positions`` is None: pixels have no metric position without depth and poses. Use
  :func:`~quash_plugins.adapters.pixel_coordinates` for ``(x, y, frame)`` of any items.
- Colours come from the RGB image with the same stem, searched in the feature directory,
  in ``images=`` and in the usual sibling folders (``rgb``, ``color``, ``images``,
  ``results``...). ConceptFusion extracts features at a reduced size (e.g. 240 x 320),
  so an image of another size is resized to the feature resolution (bilinear). Frames
  without an image get grey. With no image at all, ``colors`` is None.
"""

from __future__ import annotations

import logging
import re
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import MapFormatError, QuashError
from ..core.interfaces import MapAdapter
from ..core.types import FrameInfo, LatentMap
from ._rows import ConcatRows

log = logging.getLogger(__name__)

FEATURE_SUFFIXES = (".pt", ".pth", ".npy")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".PNG", ".JPG", ".JPEG")
#: Sibling folders searched for RGB frames (relative to the feature directory's parent).
IMAGE_DIRS = ("rgb", "color", "colors", "image", "images", "results", "frames")
#: Files that belong to other layouts (VLMaps 2D grids, OpenLex3D) and are never frames.
_NOT_FRAMES = re.compile(r"^(grid_|weight_|color_top_down|obstacles|embeddings$|index$)")
LAYOUTS = ("auto", "hwd", "1dhw")


def _natural_key(name: str) -> list[Any]:
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", name)]


def _torch():
    try:
        import torch
    except ImportError:
        raise QuashError(
            'Reading .pt feature maps needs torch: pip install "quash-plugins[clip]"'
        ) from None
    return torch


def _load_tensor(path: Path) -> np.ndarray:
    """A bare tensor saved with ``torch.save``, as numpy (memory-mapped where possible)."""
    torch = _torch()
    try:
        try:
            obj = torch.load(path, map_location="cpu", weights_only=True, mmap=True)
        except RuntimeError as exc:  # legacy (non-zip) files cannot be memory-mapped
            if "mmap" not in str(exc):
                raise
            obj = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - torch raises many types for bad files
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise MapFormatError(
            f"{path}: not a readable tensor file ({msg}). Only bare tensors saved with "
            "torch.save are read, with weights_only=True (no pickled objects)."
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
    key = next((k for k in keys if isinstance(obj[k], _torch().Tensor)), "KEY")
    return (
        f" (keys: {shown}). Save the feature tensor itself, one file per frame: "
        f"torch.save(d[{key!r}], {str(path.name)!r})."
    )


def _load_array(path: Path) -> np.ndarray:
    if path.suffix == ".npy":
        try:
            return np.load(path, mmap_mode="r", allow_pickle=False)
        except (ValueError, OSError, EOFError) as exc:
            raise MapFormatError(f"{path}: not a readable .npy array ({exc}).") from None
    return _load_tensor(path)


def _frame_layout(shape: tuple[int, ...], layout: str, path: Path) -> tuple[int, int, int, str]:
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
            raise MapFormatError(f"{path}: expected (1, D, h, w); got shape {tuple(shape)}.")
        _, d, h, w = shape
    else:
        if len(shape) != 3:
            raise MapFormatError(f"{path}: expected (H, W, D); got shape {tuple(shape)}.")
        h, w, d = shape
    if min(h, w, d) <= 0:
        raise MapFormatError(f"{path}: field 'embeddings' is empty (shape {tuple(shape)}).")
    return int(h), int(w), int(d), layout


def _as_rows(arr: np.ndarray, layout: str) -> np.ndarray:
    """``(H*W, D)`` view of one frame (a transposed view for the (1, D, h, w) layout)."""
    if layout == "1dhw":
        d = arr.shape[1]
        return arr[0].reshape(d, -1).T
    return arr.reshape(-1, arr.shape[-1])


def list_feature_files(folder: Path) -> list[Path]:
    files = [
        p
        for p in folder.iterdir()
        if p.is_file() and p.suffix in FEATURE_SUFFIXES and not _NOT_FRAMES.match(p.stem)
    ]
    return sorted(files, key=lambda p: _natural_key(p.stem))


def _check_options(opts: dict[str, Any]) -> None:
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


def _refuse_shared_stems(files: list[Path]) -> None:
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


def _refuse_unmatched_images(images: str, files: list[Path]) -> None:
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


def _images_only_hint(path: Path) -> str:
    """Said when a folder without features holds images: the RGB folder was given."""
    if not path.is_dir() or not any(p.suffix in IMAGE_SUFFIXES for p in path.iterdir()):
        return ""
    return (
        " It holds images: pass the folder of their feature files (ConceptFusion's "
        "saved-feat/); the images are found beside it, or name them with -o images=DIR."
    )


def _find_image(stem: str, dirs: list[Path]) -> Path | None:
    for d in dirs:
        for suffix in IMAGE_SUFFIXES:
            p = d / f"{stem}{suffix}"
            if p.is_file():
                return p
    return None


def _read_rgb(path: Path, height: int, width: int) -> np.ndarray | None:
    """``(H, W, 3)`` uint8, resized (bilinear) to the feature resolution when it differs."""
    try:
        from PIL import Image
    except ImportError:  # pragma: no cover - pillow ships with matplotlib
        log.warning("Pillow is not installed; colours are not read from %s", path)
        return None
    try:
        with Image.open(path) as im:
            im = im.convert("RGB")
            if im.size != (width, height):
                im = im.resize((width, height), Image.Resampling.BILINEAR)
            return np.asarray(im, dtype=np.uint8)
    except OSError as exc:
        log.warning("cannot read image %s (%s); using grey", path, exc)
        return None


class ImageFeaturesAdapter(MapAdapter):
    """Read a directory of per-image feature maps (``<stem>.pt`` / ``<stem>.npy``).

    Parameters
    ----------
    images
        Directory of the RGB frames. Default: the feature directory and its usual siblings.
    colors
        Read RGB images for colours (False skips them).
    layout
        ``"auto"`` (rank 3 = ``(H, W, D)``, rank 4 = ``(1, D, h, w)``), ``"hwd"`` or ``"1dhw"``.
    cache_frames
        How many frames are kept loaded while reading rows.

    Examples
    --------
    >>> from quash_plugins import registry
    >>> lmap = registry.create("adapters", "image-features").read("saved-feat")  # doctest: +SKIP
    >>> [f.frame_id for f in lmap.frames]  # doctest: +SKIP
    ['frame000000', 'frame000100']
    """

    name = "image-features"
    priority = 1

    def __init__(
        self,
        images: str | None = None,
        colors: bool = True,
        layout: str = "auto",
        cache_frames: int = 8,
    ) -> None:
        self.images = images
        self.colors = colors
        self.layout = layout
        self.cache_frames = cache_frames

    def sniff(self, source: Any) -> bool:
        try:
            if not isinstance(source, (str, Path)):
                return False
            p = Path(source)
            if p.is_file() and p.suffix == ".npy":  # one frame, by its header's shape
                shape = np.load(p, mmap_mode="r", allow_pickle=False).shape
                return not _NOT_FRAMES.match(p.stem) and (
                    len(shape) == 3 or (len(shape) == 4 and shape[0] == 1)
                )
            if p.is_file():
                return p.suffix in (".pt", ".pth")
            if not p.is_dir() or (p / "pc_points.h5").exists():
                return False
            for q in p.iterdir():
                if q.is_file() and q.suffix in FEATURE_SUFFIXES and not _NOT_FRAMES.match(q.stem):
                    return True
            return False
        except (OSError, ValueError):
            return False

    def read(self, source: Any, **options: Any) -> LatentMap:
        opts = self.options(options)
        _check_options(opts)
        path = Path(source).expanduser()
        if path.is_file():
            folder, files = path.parent, [path]
        elif path.is_dir():
            folder, files = path, list_feature_files(path)
        else:
            raise MapFormatError(f"Map not found: {path}")
        if not files:
            raise MapFormatError(
                f"{path}: no feature maps (<stem>.pt or <stem>.npy) found; the map is empty."
                f"{_images_only_hint(path)}"
            )
        _refuse_shared_stems(files)

        shapes, dtypes, layouts = [], [], []
        for f in files:
            arr = _load_array(f)
            h, w, d, lay = _frame_layout(tuple(arr.shape), opts["layout"], f)
            if arr.dtype.kind not in "fiu":
                raise MapFormatError(f"{f}: field 'embeddings' must hold numbers; got {arr.dtype}.")
            if shapes and d != shapes[0][2]:
                raise MapFormatError(
                    f"{f}: feature dimension {d} differs from {files[0].name}'s {shapes[0][2]}; "
                    "all frames must come from the same model."
                )
            shapes.append((h, w, d))
            dtypes.append(arr.dtype)
            layouts.append(lay)
            del arr
        dim = shapes[0][2]
        dtype = np.result_type(*dtypes)

        image_dirs = self._image_dirs(folder, opts["images"])
        frames: list[FrameInfo] = []
        offset = 0
        images: list[Path | None] = []
        for f, (h, w, _) in zip(files, shapes):
            img = _find_image(f.stem, image_dirs) if opts["colors"] else None
            images.append(img)
            frames.append(FrameInfo(f.stem, h, w, offset, str(img.absolute()) if img else None))
            offset += h * w

        def loader(f: Path, lay: str):
            return lambda: _as_rows(_load_array(f), lay)

        def locate(i: int, row: int) -> str:
            y, x = divmod(row, frames[i].width)
            return f"pixel (x={x}, y={y})"

        emb = ConcatRows(
            [fr.size for fr in frames],
            [loader(f, lay) for f, lay in zip(files, layouts)],
            dim,
            dtype,
            [str(f) for f in files],
            locate=locate,
            cache=opts["cache_frames"],
        )
        if opts["images"] is not None and opts["colors"] and not any(images):
            _refuse_unmatched_images(opts["images"], files)
        colors = self._colors(frames, images) if any(images) else None
        log.debug(
            "image-features: %d frames, %d pixels x %d (%s)", len(frames), emb.shape[0], dim, dtype
        )
        return LatentMap(
            embeddings=emb,
            kind="pixels",
            colors=colors,
            frames=frames,
            normalize=True,
            source={
                "adapter": self.name,
                "path": str(path),
                "layout": sorted(set(layouts)),
                "images": [str(d) for d in image_dirs],
            },
        )

    @staticmethod
    def _image_dirs(folder: Path, images: str | None) -> list[Path]:
        if images is not None:
            d = Path(images).expanduser()
            if not d.is_dir():
                raise MapFormatError(f"images={images!r}: not a directory.")
            return [d]
        dirs = [folder] + [folder / name for name in IMAGE_DIRS]
        dirs += [folder.parent / name for name in IMAGE_DIRS]
        return [d for d in dirs if d.is_dir()]

    @staticmethod
    def _colors(frames: list[FrameInfo], images: list[Path | None]) -> np.ndarray:
        total = sum(f.size for f in frames)
        out = np.full((total, 3), 128, dtype=np.uint8)
        for fr, img in zip(frames, images):
            if img is None:
                continue
            rgb = _read_rgb(img, fr.height, fr.width)
            if rgb is not None:
                out[fr.offset : fr.offset + fr.size] = rgb.reshape(-1, 3)
        missing = sum(1 for i in images if i is None)
        if missing:
            log.warning(
                "%d of %d frames have no RGB image; they are shown grey", missing, len(frames)
            )
        return out

    def write_example(self, directory: Path) -> Path:
        """Write two ConceptFusion-style frames (``.pt``, float16) with PNG images."""
        torch = _torch()
        folder = Path(directory) / "saved-feat"
        folder.mkdir(parents=True, exist_ok=True)
        rng = np.random.default_rng(0)
        for i in range(2):
            feat = rng.normal(size=(6, 8, 16)).astype(np.float32)
            feat /= np.linalg.norm(feat, axis=-1, keepdims=True)
            feat[:2, :3] = 0
            torch.save(torch.from_numpy(feat).half(), folder / f"frame{i:06d}.pt")
            rgb = rng.integers(0, 255, size=(6, 8, 3), dtype=np.uint8)
            try:
                from PIL import Image

                Image.fromarray(rgb).save(folder / f"frame{i:06d}.png")
            except ImportError:  # pragma: no cover
                pass
        return folder
