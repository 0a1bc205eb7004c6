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
- Camera files beside the frames (``poses.npy``, ``intrinsics.npy``, a ``(4, 4)`` array,
  an ``(N, 4, 4)`` trajectory whose D is not the frames') are skipped with an INFO line
  (:func:`~quash_plugins.adapters._feature_files.split_frames`), not read as frames.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import MapFormatError
from ..core.interfaces import MapAdapter
from ..core.progress import progress
from ..core.types import FrameInfo, LatentMap, record_inputs
from ._feature_files import (
    FEATURE_SUFFIXES,
    IMAGE_DIRS,
    SIDE_FILES,
    as_rows,
    check_options,
    find_image,
    frame_layout,
    images_only_hint,
    import_torch,
    list_feature_files,
    load_array,
    not_a_frame_name,
    read_rgb,
    refuse_shared_stems,
    refuse_unmatched_images,
    split_frames,
)
from ._openscene import is_fused_file, is_scene_file
from ._rows import ConcatRows

log = logging.getLogger(__name__)


def _dim_note(path: Path, hwd: tuple[int, int, int], layout: str, asked: str) -> dict[str, str]:
    """How D was read, for a dimension mismatch to explain (``source["dim_note"]``): a
    ``(D, h, w)`` frame, LSeg's output without its leading 1, reads as ``(H, W, D)``; a
    ``(1, H, W, D)`` frame, ConceptFusion's before its ``[0]``, as ``(1, D, h, w)``."""
    h, w, d = hwd
    if asked == "auto" and layout == "1dhw" and w > d:  # w > D: (1, H, W, D)?
        return {
            "dim_note": f"D is axis 1 of {path.name}, read as (1, D, h, w) = {(1, d, h, w)}; "
            "if it is (1, H, W, D), save features[0], (H, W, D), as ConceptFusion's "
            "extractor does"
        }
    if asked != "auto" or layout != "hwd" or hwd[0] <= hwd[2]:  # H > D: (D, h, w)?
        return {}
    return {
        "dim_note": f"D is the last axis of {path.name}, read as (H, W, D) = {hwd}; if it "
        "is (D, h, w), save it with a leading 1, (1, D, h, w), as LSeg's extractor does"
    }


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
                return _npy_frame(p)
            if p.is_file():  # not OpenScene's scene points (numpy arrays in a .pth)
                return p.suffix in (".pt", ".pth") and not is_scene_file(p)
            if not p.is_dir() or (p / "pc_points.h5").exists():
                return False
            # a .pt, or a .npy shaped as a frame: a folder holding only other arrays
            # (labels.npy, poses.npy beside a saved-map/) is no feature folder, nor one
            # of OpenScene's fused <scene>_<n>.pt (dicts, read one file at a time)
            return any(
                q.is_file()
                and q.suffix in FEATURE_SUFFIXES
                and not not_a_frame_name(q.stem)
                and (_npy_frame(q) if q.suffix == ".npy" else not is_fused_file(q))
                for q in p.iterdir()
            )
        except (OSError, ValueError):
            return False

    def unrecognised_hint(self, source: Any) -> str:
        """For a folder of RGB images without features: pass the features' folder (what
        :meth:`read` says when named)."""
        try:
            path = Path(source).expanduser() if isinstance(source, (str, Path)) else None
            if path is None:
                return ""
            return images_only_hint(path).strip() or _unreadable_frames_hint(path)
        except OSError:
            return ""

    def read(self, source: Any, **options: Any) -> LatentMap:
        opts = self.options(options)
        check_options(opts)
        path = Path(source).expanduser()
        skipped: list[str] = []
        if path.is_file():
            folder, files = path.parent, [path]
        elif path.is_dir():
            folder, files = path, list_feature_files(path)
        else:
            raise MapFormatError(f"Map not found: {path}")
        found = {}
        with progress(len(files), f"reading {len(files)} feature files") as advance:
            for f in files:
                if not SIDE_FILES.match(f.stem) or f == path:
                    found[f] = _header(f)
                advance(1)
        if path.is_dir():
            files, skipped = split_frames(
                files, {f: a.shape for f, a in found.items()}, opts["layout"]
            )
        if skipped:
            log.info(
                "%s: skipped %d file(s) that are no frame feature maps: %s",
                path,
                len(skipped),
                "; ".join(skipped),
            )
        if not files:
            also = f" (skipped: {'; '.join(skipped)})" if skipped else ""
            raise MapFormatError(
                f"{path}: no feature maps (<stem>.pt or <stem>.npy) found; the map is empty"
                f"{also}.{images_only_hint(path)}"
            )
        refuse_shared_stems(files)

        shapes, dtypes, layouts = [], [], []
        for f in files:
            arr = found[f]
            h, w, d, lay = frame_layout(tuple(arr.shape), opts["layout"], f)
            if arr.dtype.kind not in "fiu":
                raise MapFormatError(f"{f}: field 'embeddings' must hold numbers; got {arr.dtype}.")
            if shapes and d != shapes[0][2]:
                stray = (
                    f" If {f.name} is no frame feature map, move it out of the folder."
                    if f.suffix == ".npy"
                    else ""
                )
                raise MapFormatError(
                    f"{f}: feature dimension {d} differs from {files[0].name}'s {shapes[0][2]}; "
                    f"all frames must come from the same model.{stray}"
                )
            shapes.append((h, w, d))
            dtypes.append(arr.dtype)
            layouts.append(lay)
        dim = shapes[0][2]
        dtype = np.result_type(*dtypes)

        image_dirs = self._image_dirs(folder, opts["images"])
        frames: list[FrameInfo] = []
        offset = 0
        images: list[Path | None] = []
        for f, (h, w, _) in zip(files, shapes):
            img = find_image(f.stem, image_dirs) if opts["colors"] else None
            images.append(img)
            frames.append(FrameInfo(f.stem, h, w, offset, str(img.absolute()) if img else None))
            offset += h * w

        def loader(f: Path, lay: str):
            return lambda: as_rows(load_array(f), lay)

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
            refuse_unmatched_images(opts["images"], files)
        if opts["images"] is None and opts["colors"] and not any(images):
            log.info(
                "%s: no RGB image named after a frame (%s.png, .jpg) in %s or its usual "
                "folders (%s); the map has no colours: name the images' folder with "
                "-o images=DIR (images: DIR in the config's adapter section)",
                path,
                files[0].stem,
                folder,
                ", ".join(IMAGE_DIRS),
            )
        colors = self._colors(frames, images, image_dirs) if any(images) else None
        log.debug(
            "image-features: %d frames, %d pixels x %d (%s)", len(frames), emb.shape[0], dim, dtype
        )
        return LatentMap(
            embeddings=emb,
            kind="pixels",
            colors=colors,
            frames=frames,
            normalize=True,
            source=record_inputs(
                {
                    "adapter": self.name,
                    "path": str(path),
                    "layout": sorted(set(layouts)),
                    "images": [str(d) for d in image_dirs],
                    **({"skipped": skipped} if skipped else {}),
                    **_dim_note(files[0], shapes[0], layouts[0], opts["layout"]),
                },
                # the feature files when ``path`` is one, and the images used for colour
                # outside the feature folder (a folder stands for what it holds)
                *_outside(path, [*files, *(i for i in images if i is not None)]),
            ),
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
    def _colors(
        frames: list[FrameInfo], images: list[Path | None], image_dirs: list[Path]
    ) -> np.ndarray:
        total = sum(f.size for f in frames)
        out = np.full((total, 3), 128, dtype=np.uint8)
        found = sum(1 for i in images if i is not None)
        turned: list[str] = []
        with progress(found, f"reading {found} RGB images") as advance:
            for fr, img in zip(frames, images):
                if img is None:
                    continue
                rgb = read_rgb(img, fr.height, fr.width, turned)
                if rgb is not None:
                    out[fr.offset : fr.offset + fr.size] = rgb.reshape(-1, 3)
                advance(1)
        if turned:
            log.warning(
                "%d of %d RGB images are turned against their feature maps (width x "
                "height: %s%s), and each is resized to its map's size. That is right when "
                "the extractor resized them so (ConceptFusion's desired_height x "
                "desired_width ignores orientation); otherwise the frames were saved with "
                "height and width swapped, (W, H, D) or (1, D, w, h), and their colours "
                "and per-image masks do not line up with the images: save each frame as "
                "(H, W, D) (from (D, H, W): features.permute(1, 2, 0)) or (1, D, h, w)",
                len(turned),
                found,
                "; ".join(turned[:3]),
                ", ..." if len(turned) > 3 else "",
            )
        missing = [fr.frame_id for fr, i in zip(frames, images) if i is None]
        if missing:
            log.warning(
                "%d of %d frames have no RGB image (%s%s): none named after the frame "
                "(%s.png, .jpg, .jpeg) in %s; they are shown grey. Put their images there "
                "under the frames' names, or name the images' folder with -o images=DIR",
                len(missing),
                len(frames),
                ", ".join(missing[:3]),
                ", ..." if len(missing) > 3 else "",
                missing[0],
                ", ".join(str(d) for d in image_dirs),
            )
        return out

    def write_example(self, directory: Path) -> Path:
        """Write two ConceptFusion-style frames (``.pt``, float16) with PNG images."""
        torch = import_torch()
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


def _outside(path: Path, files: list[Path]) -> list[Path]:
    """``files`` that do not lie in the folder ``path`` (all of them when it is a file)."""
    if not path.is_dir():
        return files
    root = path.resolve()
    return [f for f in files if root not in f.resolve().parents]


class _Header:
    """A frame file's shape and dtype, read once (``np.load`` of a ``.npy`` reads its
    header; a ``.pt`` is loaded memory-mapped); the rows are loaded later, when read."""

    def __init__(self, shape: tuple[int, ...], dtype: np.dtype) -> None:
        self.shape, self.dtype = tuple(int(n) for n in shape), np.dtype(dtype)


def _header(path: Path) -> _Header:
    arr = load_array(path)
    return _Header(arr.shape, arr.dtype)


def _unreadable_frames_hint(folder: Path, limit: int = 256) -> str:
    """For a folder whose frame files numpy cannot read at all (each cut short, or of
    Python objects), so that no adapter recognises it: name them, and the adapter that
    says why for each. ``""`` when there are none (or it is no folder)."""
    if not folder.is_dir():
        return ""
    bad = []
    for q in sorted(folder.iterdir())[:limit]:
        if q.is_file() and q.suffix == ".npy" and not not_a_frame_name(q.stem):
            try:
                np.load(q, mmap_mode="r", allow_pickle=False)
            except (OSError, ValueError, EOFError):
                bad.append(q.name)
    if not bad:
        return ""
    shown = ", ".join(bad[:3]) + (f" and {len(bad) - 3} more" if len(bad) > 3 else "")
    return (
        f"It holds .npy files that numpy cannot read ({shown}): if they are per-image "
        "features, pass --adapter image-features, which names what is wrong with them."
    )


def _npy_frame(path: Path) -> bool:
    """True when ``path`` is a ``.npy`` whose header is a frame's shape: ``(H, W, D)`` or
    ``(1, D, h, w)`` (only the header is read); never for a name of :data:`NOT_FRAMES`
    or :data:`SIDE_FILES` (``poses.npy``, ``intrinsics.npy``)."""
    if not_a_frame_name(path.stem):
        return False
    try:
        shape = np.load(path, mmap_mode="r", allow_pickle=False).shape
    except (OSError, ValueError):
        return False
    return len(shape) == 3 or (len(shape) == 4 and shape[0] == 1)
