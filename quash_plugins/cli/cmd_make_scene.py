"""``quash make-scene``: write the labelled 3D proxy scene and its taxonomy."""

from __future__ import annotations

import argparse
import dataclasses

NAME = "make-scene"
HELP = "Generate a labelled 3D indoor proxy scene (NPZ) and its taxonomy YAML."
ORDER = 32
DESCRIPTION = """\
Rooms with floor, walls and ceiling, a few dozen objects of 32 classes, surface voxels
in metres with per-class colours. Each voxel's embedding is the normalised mean of a few
"appearance" names of its class, embedded by a real text encoder, blended with neighbours
at boundaries, mixed with other objects (semantic confusion), plus noise and a constant
modality offset. OUT.taxonomy.yaml holds only "language" names, disjoint from the
appearance names; OUT.queries.yaml lists present labels and absence queries."""
EPILOG = """\
examples:
  quash make-scene scene.npz --seed 1
  quash make-scene tiny.npz --rooms 1 --voxel-size 0.25 --encoder minilm
  quash eval scene.npz -c my-method.yaml --absent piano,bathtub"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    from ..demo.scene import SceneOptions

    p.add_argument("out", metavar="OUT.npz", help="Output map (our NPZ format).")
    p.add_argument(
        "--encoder",
        default="minilm",
        help="Registered encoder that embeds the names (default: minilm).",
    )
    p.add_argument(
        "--encoder-file",
        default=None,
        help="'file' parameter of the encoder (e.g. a table encoder's NPZ/YAML).",
    )
    p.add_argument("--no-cache", action="store_true", help="Do not use the text-embedding cache.")
    defaults = SceneOptions()
    for f in dataclasses.fields(SceneOptions):
        v = getattr(defaults, f.name)
        p.add_argument(
            f"--{f.name.replace('_', '-')}",
            type=type(v),
            default=v,
            metavar=type(v).__name__.upper(),
            help=f"(default: {v})",
        )


def run(args: argparse.Namespace) -> int:
    from ..core import registry
    from ..demo.scene import SceneOptions, make_scene, write_scene
    from ..engine.cache import open_cache
    from ._output import console

    opts = SceneOptions(**{f.name: getattr(args, f.name) for f in dataclasses.fields(SceneOptions)})
    params = {"file": args.encoder_file} if args.encoder_file else {}
    encoder = registry.create("encoders", args.encoder, **params)
    scene = make_scene(encoder, opts, cache=open_cache(not args.no_cache))
    paths = write_scene(scene, args.out, opts)
    out = console()
    out.print(
        f"{scene.map.n} voxels, {scene.n_objects} objects, rooms: "
        f"{', '.join(scene.room_types)} (seed {opts.seed}, encoder {encoder.name})"
    )
    for k, v in paths.items():
        out.print(f"wrote {k}: {v}")
    return 0
