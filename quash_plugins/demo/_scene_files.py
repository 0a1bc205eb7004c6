"""The files of a proxy scene: the NPZ map, its taxonomy and its queries.

:func:`write_scene` writes them, :func:`scene_paths` names them and
:func:`is_scene_file` tells a file an earlier :func:`write_scene` wrote (replaced
without ``--force``). :mod:`quash_plugins.demo.scene` re-exports all three.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..core.errors import ConfigError

if TYPE_CHECKING:
    from .scene import Scene, SceneOptions

_TAXONOMY_HEAD = "# language names only: disjoint from the appearance names that built the voxels\n"


def scene_paths(out: str | Path) -> dict[str, Path]:
    """The files :func:`write_scene` writes for ``OUT.npz``."""
    out = Path(out)
    stem = out.with_suffix("")
    return {
        "map": out,
        "taxonomy": Path(f"{stem}.taxonomy.yaml"),
        "queries": Path(f"{stem}.queries.yaml"),
        "open_queries": Path(f"{stem}.open-queries.yaml"),
    }


def is_scene_file(path: str | Path) -> bool:
    """True when ``path`` is one of the files a previous :func:`write_scene` wrote.

    The queries file is a mapping with ``present``, ``absent`` and ``room_types``; the
    taxonomy starts with the scene's comment; the map is an NPZ map whose queries file
    is such a record. These may be replaced without ``--force``; nothing else may.
    """
    import zipfile

    p = Path(path)
    try:
        if p.name.endswith(".queries.yaml"):
            from ..core.yaml_files import load_yaml

            data, _ = load_yaml(p)
            return isinstance(data, dict) and {"present", "absent", "room_types"} <= set(data)
        if p.name.endswith(".open-queries.yaml"):
            from ..core.yaml_files import load_yaml

            data, _ = load_yaml(p)
            return isinstance(data, dict) and {"present", "absent", "kind"} <= set(data)
        if p.name.endswith(".taxonomy.yaml"):
            with open(p, encoding="utf-8") as f:
                return f.readline() == _TAXONOMY_HEAD
        if p.suffix == ".npz":
            with zipfile.ZipFile(p) as zf:
                if "embeddings.npy" not in zf.namelist():
                    return False
            return is_scene_file(scene_paths(p)["queries"])
    except (OSError, UnicodeDecodeError, zipfile.BadZipFile, ConfigError):
        return False
    return False


def write_scene(
    scene: Scene, out: str | Path, options: SceneOptions | None = None
) -> dict[str, Path]:
    """Write ``OUT.npz``, ``OUT.taxonomy.yaml`` and ``OUT.queries.yaml``; return the paths."""
    import yaml

    from ..adapters import write_npz_map
    from ..core.atomic import atomic_write

    out = Path(out)
    if out.suffix != ".npz":
        raise ConfigError(f"{out}: the scene is written as our NPZ format; use a .npz name.")
    out.parent.mkdir(parents=True, exist_ok=True)
    write_npz_map(scene.map, out)
    paths = scene_paths(out)
    tax, queries = paths["taxonomy"], paths["queries"]
    head = _TAXONOMY_HEAD
    with atomic_write(tax, suffix=".yaml") as tmp:
        Path(tmp).write_text(head + yaml.safe_dump(scene.taxonomy, sort_keys=False), "utf-8")
    present = sorted({scene.map.label_names[i] for i in np.unique(scene.map.labels)})
    info = {
        "present": present,
        "absent": scene.absent,
        "room_types": scene.room_types,
        "options": dataclasses.asdict(options) if options else None,
    }
    if scene.class_table_sha256:  # which file content built it
        info["class_table_sha256"] = scene.class_table_sha256
    if scene.absent_lookalikes:  # appearance names that read as an absent label
        info["absent_lookalikes"] = scene.absent_lookalikes
    with atomic_write(queries, suffix=".yaml") as tmp:
        Path(tmp).write_text(yaml.safe_dump(info, sort_keys=False), "utf-8")
    open_info = {
        "kind": "open-vocabulary queries: sub-class names and free text, with their label",
        "present": dict(scene.open_present),
        "absent": list(scene.open_absent),
    }
    if scene.absent_lookalikes:
        open_info["absent_lookalikes"] = scene.absent_lookalikes
    with atomic_write(paths["open_queries"], suffix=".yaml") as tmp:
        Path(tmp).write_text(yaml.safe_dump(open_info, sort_keys=False), "utf-8")
    return {**paths}
