"""``quash make-scene``: write the labelled 3D proxy scene and its taxonomy."""

from __future__ import annotations

import argparse
import dataclasses

NAME = "make-scene"
HELP = "Generate a labelled 3D indoor proxy scene (NPZ) and its taxonomy YAML."
ORDER = 32
DESCRIPTION = """\
Rooms with floor, walls and ceiling, a few dozen objects of 32 classes
(--classes b: a second table of 34 other labels with other names; --classes
FILE.yaml: a table of your own, see --show-classes), surface voxels in metres
with per-class colours. Each voxel's embedding is the normalised mean of a few
"appearance" names of its class, embedded by a real text encoder, blended with
neighbours at boundaries, mixed with other objects (semantic confusion), plus
noise and a constant modality offset (--gap-class, --gap-instance,
--distortion: a gap that is not one constant vector). OUT.taxonomy.yaml holds
only "language" names, disjoint from the appearance names; OUT.queries.yaml
lists present labels and absence queries, OUT.open-queries.yaml open-vocabulary
ones (sub-class names and free text with their label, absent ones). Both are
`quash eval --queries-file` files. An appearance name that the encoder reads as
an absent label (nearer its names than its own class's by more than 0.2 in
cosine) is warned about and listed in both query files (absent_lookalikes): the
map's features would hold that absent object. Existing files are replaced only
when they are a previous make-scene output, or with --force."""
EPILOG = """\
examples:
  quash make-scene scene.npz --seed 1
  quash make-scene tiny.npz --rooms 1 --voxel-size 0.25 --encoder minilm
  quash make-scene held-out.npz --classes b --gap-class 0.5 \\
      --gap-instance 0.3 --distortion 0.5
  quash make-scene --show-classes > my-classes.yaml  # table A, a file to edit
  quash make-scene mine.npz --classes my-classes.yaml --noise 2
  quash eval scene.npz -c my-method.yaml --absent piano,bathtub
  quash eval scene.npz -c my-method.yaml --queries-file scene.open-queries.yaml"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    from ..demo.scene import SceneOptions

    p.add_argument("out", metavar="OUT.npz", nargs="?", help="Output map (our NPZ format).")
    p.add_argument(
        "--show-classes",
        action="store_true",
        help="Print the class table that --classes names as YAML (a file to start a table "
        "of your own from) and exit.",
    )
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
    p.add_argument(
        "--encoder-option",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        dest="encoder_option",
        help="A parameter of the encoder, e.g. --encoder-option dim=384 (values parsed as "
        "YAML); repeatable. A query must then use the same encoder and parameters.",
    )
    p.add_argument("--no-cache", action="store_true", help="Do not use the text-embedding cache.")
    p.add_argument(
        "--force",
        action="store_true",
        help="Replace existing files that are not a previous make-scene output.",
    )
    defaults = SceneOptions()
    for f in dataclasses.fields(SceneOptions):
        v = getattr(defaults, f.name)
        p.add_argument(
            f"--{f.name.replace('_', '-')}",
            type=type(v),
            default=v,
            metavar="TABLE" if f.name == "classes" else type(v).__name__.upper(),
            help=_HELP.get(f.name, f"(default: {v})"),
        )


_HELP = {
    "classes": "The class table: a (default), b, or a class-table YAML file of your own "
    "(labels, appearance and language names, rooms; --show-classes prints the format).",
}


def run(args: argparse.Namespace) -> int:
    from ..core import registry
    from ..core.errors import QuashError, UsageError
    from ..demo.scene import SceneOptions, make_scene, write_scene
    from ..engine.cache import open_cache
    from ._config_opts import key_values
    from ._output import say_done

    opts = SceneOptions(**{f.name: getattr(args, f.name) for f in dataclasses.fields(SceneOptions)})
    if args.show_classes:
        return _show_classes(opts.classes)
    if args.out is None:
        raise UsageError("give OUT.npz, the map to write (or --show-classes).")
    opts.validate()  # before the encoder loads
    _check_outputs(args)
    params = {"file": args.encoder_file} if args.encoder_file else {}
    params.update(key_values(args.encoder_option, "--encoder-option"))
    try:
        encoder = registry.create("encoders", args.encoder, **params)
    except QuashError as exc:
        raise UsageError(f"--encoder {args.encoder}: {exc}") from exc.__cause__
    scene = make_scene(encoder, opts, cache=open_cache(not args.no_cache))
    paths = write_scene(scene, args.out, opts)
    say_done(
        args,
        f"{scene.map.n} voxels, {scene.n_objects} objects, rooms: "
        f"{', '.join(scene.room_types)} (seed {opts.seed}, encoder {encoder.name})",
    )
    for k, v in paths.items():
        say_done(args, f"wrote {k}: {v}")
    return 0


def _show_classes(name: str) -> int:
    import sys

    import yaml

    from ..demo.class_file import class_table_data
    from ..demo.scene import class_set

    data = class_table_data(class_set(name))
    sys.stdout.write(
        f"# quash make-scene class table {data['name']!r}: edit it, then\n"
        "# quash make-scene OUT.npz --classes THIS.yaml (format: quash_plugins/demo/class_file.py)\n"
    )

    class Dumper(yaml.SafeDumper):  # lists of names on one line each
        pass

    def flow(dumper, value):
        short = all(isinstance(v, (str, int, float)) for v in value)
        return dumper.represent_sequence("tag:yaml.org,2002:seq", value, flow_style=short)

    Dumper.add_representer(list, flow)
    sys.stdout.write(yaml.dump(data, Dumper=Dumper, sort_keys=False, allow_unicode=True, width=100))
    return 0


def _check_outputs(args: argparse.Namespace) -> None:
    """Refuse, before any work, to replace files that make-scene did not write."""
    from ..core.atomic import check_output
    from ..core.errors import UsageError
    from ..demo.scene import is_scene_file, scene_paths

    if not str(args.out).endswith(".npz"):
        raise UsageError(f"{args.out}: the scene is written as our NPZ format; use a .npz name.")
    from ..demo.class_file import is_class_file

    # the class table is read too: never replaced by an output named like it
    inputs = (args.encoder_file, args.classes if is_class_file(args.classes) else None)
    for path in scene_paths(args.out).values():
        check_output(path, inputs, what="OUT", overwrite=args.force, replaceable=is_scene_file)
