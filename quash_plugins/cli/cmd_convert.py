"""``quash convert``: any readable map to the portable NPZ format (or a Zarr store)."""

from __future__ import annotations

import argparse
from typing import Any

NAME = "convert"
HELP = (
    "Convert any readable map (VLMaps, ConceptFusion, OpenScene...) to .npz, zarr, OpenLex3D "
    "or VLMaps."
)
ORDER = 40
DESCRIPTION = """\
Read a map with any adapter and write it as quash-plugins' portable NPZ (embeddings,
positions, colours, labels...), as a Zarr store when DST ends in .zarr, or, with
--format openlex3d, as OpenLex3D's prediction folder DST/ (embeddings.npy, index.npy,
point_cloud.pcd; a map of objects, such as ConceptGraphs', keeps one row per object).
With --format vlmaps, a voxel map becomes VLMaps' own HDF5 save layout,
DST/vlmap_cam/vlmaps_cam.h5df (the camera-base layout: it stores its cell size and
origin, and its cells are [row, height, col] with y up, so a z-up map is turned rigidly
to y-up and reads back so; labels go to grid_semantic and vlmap_cam/obj2cls_dict.txt,
which VLMaps itself ignores). A taxonomy beside SRC (SRC.taxonomy.yaml, as make-scene
writes it; for a VLMaps scene folder, the one beside the .h5df read; for a folder
map, FOLDER.taxonomy.yaml beside the folder read, as ConceptFusion's
saved-map/pointclouds.taxonomy.yaml) is copied to
DST.taxonomy.yaml for a .npz or .zarr DST (with --format openlex3d, beside the folder
DST; with --format vlmaps, to DST/vlmap_cam/vlmaps_cam.taxonomy.yaml), never over a
file, so the converted map
answers as SRC does. The input is only read; the
output appears atomically. Lazy maps (HDF5, per-image features) are streamed block by
block, so the map is never held whole in memory. DST is never SRC (nor inside it); an
existing DST is replaced only with --force (with --format openlex3d, a previous export of
quash is replaced without it and any other folder never; with --format vlmaps DST may be
an existing folder, and the files written into it are replaced only with --force)."""
EPILOG = """\
examples:
  quash convert saved-map room0.npz                 # ConceptFusion pointclouds/
  quash convert vlmap/vlmaps.h5df office.npz --adapter vlmaps
  quash convert saved-feat frames.npz --adapter image-features
  quash convert map.pkl.gz map.npz --allow-pickle   # ConceptGraphs, trusted files only
  quash convert saved-map room0.zarr                # chunked Zarr store (needs [dask])
  quash convert saved-map preds/quash/replica/room0 --format openlex3d
  quash convert saved-map room0.npz --up +y         # a cloud in a y-up dataset frame
  quash make-scene scene.npz && quash convert scene.npz vl --format vlmaps
                                                    # try the VLMaps drop-in offline:
  quash query vl chair -c demo:quash-labels         # reads vl/vlmap_cam/vlmaps_cam.h5df"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    from ..core.types import UP_CHOICES

    p.add_argument("source", metavar="SRC", help="Map file or directory to read.")
    p.add_argument(
        "destination",
        metavar="DST",
        help="Output: DST.npz, DST.zarr, or a folder (openlex3d, vlmaps).",
    )
    p.add_argument(
        "--format",
        default="auto",
        choices=("auto", "npz", "zarr", "openlex3d", "vlmaps"),
        help="Output format (default: auto, by DST's suffix). openlex3d writes OpenLex3D's "
        "prediction folder: embeddings.npy, index.npy and point_cloud.pcd (one row per "
        "point, index arange; a map of objects keeps its object table and point-to-object "
        "index). vlmaps writes DST/vlmap_cam/vlmaps_cam.h5df in VLMaps' save layout (voxel "
        "maps only).",
    )
    p.add_argument(
        "--adapter", default="auto", help="Adapter name, or 'auto' to sniff the format (default)."
    )
    p.add_argument(
        "--up",
        choices=UP_CHOICES,
        default="auto",
        help="The source map's up axis, for a map whose format does not say (a ConceptFusion "
        "cloud in a y-up dataset frame): recorded in DST, and what --format vlmaps turns to "
        "VLMaps' y-up. auto (default): the axis the map's format records (VLMaps camera-base "
        "maps: +y), else +z.",
    )
    p.add_argument(
        "--allow-pickle",
        action="store_true",
        help="Allow unpickling a trusted .pkl/.pkl.gz map (ConceptGraphs). Never the default.",
    )
    p.add_argument(
        "--option",
        "-o",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="Adapter option, e.g. -o cs=0.05 -o positions=upstream (values parsed as YAML); "
        "repeatable.",
    )
    p.add_argument("--compress", action="store_true", help="Compress in-memory maps (slower).")
    p.add_argument(
        "--force",
        action="store_true",
        help="Replace an existing DST (never SRC, and a folder only if it is a zarr store; "
        "--format openlex3d replaces a previous export without it).",
    )
    p.add_argument("--json", action="store_true", help="Print a JSON summary.")


def run(args: argparse.Namespace) -> int:
    from ..adapters import convert_map, detect_adapter, read_map
    from ..core import registry
    from ..core.errors import UsageError
    from ._config_opts import adapter_options
    from ._output import print_json, say_done

    options = adapter_options(args)
    _check_destination(args)
    name = args.adapter
    if name in (None, "auto"):
        from pathlib import Path

        src = Path(args.source).expanduser()
        if not src.exists():
            raise UsageError(f"Map not found: {src}")
        name = detect_adapter(src, claimed=True)
    if args.allow_pickle:
        accepted = registry.accepted_params(registry.load("adapters", name))
        if accepted is not None and "allow_pickle" not in accepted:
            raise UsageError(f"--allow-pickle: adapter {name!r} does not read pickles.")
        options["allow_pickle"] = True
    # read here, so that the taxonomy is looked for beside the file the adapter read (a
    # VLMaps scene folder's vlmap_cam/vlmaps_cam.h5df), where the taxonomy heuristics find it
    lmap = read_map(args.source, name, **options)
    written = convert_map(
        lmap,
        args.destination,
        name,
        compress=args.compress,
        format=args.format,
        up=args.up,
    )
    taxonomy = _carry_taxonomy(lmap.source.get("path") or args.source, written)
    if args.json:
        print_json(
            {
                "source": args.source,
                "adapter": name,
                "destination": str(written),
                **({"taxonomy": str(taxonomy)} if taxonomy else {}),
            }
        )
    else:
        say_done(args, f"wrote {written} (read with adapter {name!r})")
        if taxonomy:
            say_done(args, f"wrote {taxonomy} (the map's taxonomy, copied)")
    return 0


def _carry_taxonomy(source: str, written: Any) -> Any:
    """Copy ``SRC.taxonomy.yaml`` (what ``quash make-scene`` writes beside its map, and
    what the taxonomy heuristics read beside a map) to ``DST.taxonomy.yaml`` (beside the
    ``.h5df`` that ``--format vlmaps`` writes into its folder), so that the
    converted map answers as its source does. Never replaces a file: an existing one is
    kept with a warning when it differs, or when SRC has none (it would be read as the
    converted map's). Returns the path written, or None."""
    import logging

    from ..core.atomic import atomic_write_text
    from ..heuristics import taxonomy_path_beside

    log = logging.getLogger(__name__)
    src = taxonomy_path_beside(source)
    dst = taxonomy_path_beside(written)
    if src is None or not src.is_file():
        if dst is not None and dst.exists():
            log.warning(
                "%s is beside the converted map, but %s has no taxonomy: the taxonomy "
                "heuristics read %s as this map's label list; delete it if it came with a "
                "map written there before.",
                dst,
                source,
                dst,
            )
        return None
    if dst is None:  # a path with no name (the root folder): nowhere beside it
        log.info(
            "%s is not carried to %s: give it to a taxonomy config as heuristic file: %s",
            src,
            written,
            src,
        )
        return None
    text = src.read_text(encoding="utf-8")
    if dst.exists():
        if not dst.is_file() or dst.read_text(encoding="utf-8", errors="replace") != text:
            log.warning(
                "%s is kept as it is, and differs from the source map's %s: the taxonomy "
                "heuristics read %s beside the converted map; replace it yourself if the "
                "source's is the one you want.",
                dst,
                src,
                dst,
            )
        return None
    atomic_write_text(dst, text)
    return dst


def _check_destination(args: argparse.Namespace) -> None:
    """Refuse, before reading anything, a destination that is the source or exists."""
    from ..core.atomic import check_not_input, check_output
    from ..core.errors import UsageError

    if args.format == "openlex3d":  # a folder; write_openlex3d_map replaces only its exports
        check_not_input(args.destination, (args.source,), what="DST")
        return
    if args.format == "vlmaps":  # a folder (it may exist); its files need --force
        from ..adapters import vlmaps_outputs

        check_not_input(args.destination, (args.source,), what="DST")
        for out in vlmaps_outputs(args.destination):
            check_output(out, (args.source,), what="DST", overwrite=args.force)
        return
    dst = str(args.destination).rstrip("/").lower()
    if args.format == "auto" and not dst.endswith((".npz", ".zarr")):
        raise UsageError(
            f"Destination {args.destination} must end in .npz (portable map) or .zarr (Zarr "
            "store), or pass --format openlex3d to write OpenLex3D's prediction folder."
        )
    check_output(
        args.destination,
        (args.source,),
        what="DST",
        overwrite=args.force,
        folder=dst.endswith(".zarr"),
    )
