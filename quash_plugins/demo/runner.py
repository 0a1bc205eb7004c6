"""The offline demo: the peers' rules against QuASH on the cached proxy scene.

The method configs ship as package data (``quash_plugins/data/configs/demo-*.yaml``);
:func:`demo_config_paths` lists them so users can read and reuse them.
"""

from __future__ import annotations

import logging
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from ..core.cache_dirs import cache_dir, make_private_dirs
from ..core.progress import progress
from ..engine.map_fit import same_embedding_function
from ..evaluation.report import EvalReport, evaluate
from .scene import SceneOptions, make_scene, write_scene

log = logging.getLogger(__name__)

#: Bump when the scene generator changes, so cached demo scenes are rebuilt.
SCENE_VERSION = 1
DEMO_QUERIES = (
    "chair",
    "table",
    "sofa",
    "bed",
    "lamp",
    "plant",
    "tv",
    "toilet",
    "refrigerator",
    "book",
)
DEMO_ABSENT = ("piano", "bathtub", "bicycle")
DEMO_CONFIGS = (
    "demo-vlmaps",
    "demo-conceptfusion",
    "demo-lerf",
    "demo-vlmaps-labels",
    "demo-openscene-labels",
    "demo-quash-labels",
    "demo-quash-taxonomy",
    "demo-quash-taxonomy-svm",
    "demo-quash-vocabulary",
    "demo-quash-adjectives",
)
TINY = SceneOptions(rooms=2, voxel_size=0.25, room_size=4.0, extra_objects=0)


def cache_root() -> Path:
    """``$QUASH_CACHE_DIR/demo``, else ``<user cache dir>/quash-plugins/demo``."""
    return cache_dir("demo")


def demo_config_paths() -> list[Path]:
    """The shipped demo configs, in table order."""
    base = resources.files("quash_plugins.data").joinpath("configs")
    return [Path(str(base.joinpath(f"{n}.yaml"))) for n in DEMO_CONFIGS]


def demo_scene(
    encoder: Any, tiny: bool = False, seed: int = 0, cache: Any = None, rebuild: bool = False
) -> Path:
    """Build (once) and return the cached demo scene's NPZ path.

    A cached scene that another embedding function built (its recorded
    ``encoder_fingerprint`` is neither ``encoder``'s nor one of its earlier names: other
    weights under the same encoder name) is built again: queried, it would be scored in
    another space."""
    opts = SceneOptions(**{**TINY.__dict__, "seed": seed}) if tiny else SceneOptions(seed=seed)
    tag = "tiny" if tiny else "full"
    path = cache_root() / f"scene-v{SCENE_VERSION}-{tag}-seed{seed}-{encoder.name}.npz"
    if path.exists() and not rebuild:
        built = _built_with(path)
        if built is None or same_embedding_function(encoder, built):
            log.info("demo scene from cache: %s", path)
            return path
        log.info(
            "demo scene %s was built by another embedding function (%s); building it again",
            path,
            built,
        )
    log.info("building the demo scene (%s) in %s", tag, path.parent)
    make_private_dirs(path.parent)
    write_scene(make_scene(encoder, opts, cache=cache), path, opts)
    return path


def _built_with(path: Path) -> str | None:
    """The encoder fingerprint a scene file records (None: none, or unreadable)."""
    try:
        with np.load(path, allow_pickle=False) as z:
            return str(z["encoder_fingerprint"]) if "encoder_fingerprint" in z.files else None
    except (OSError, ValueError, KeyError):
        return None


def run_demo(
    tiny: bool = False,
    seed: int = 0,
    overrides: dict[str, Any] | None = None,
    viewer: Any = None,
    configs: list[Path] | None = None,
    queries: tuple[str, ...] = DEMO_QUERIES,
    absent: tuple[str, ...] = DEMO_ABSENT,
) -> tuple[EvalReport, Path]:
    """Build or reuse the scene, evaluate every demo config, log to ``viewer`` if given."""
    from ..engine.pipeline import Quash

    overrides = dict(overrides or {})
    quashes = [Quash.from_config(p, **overrides) for p in (configs or demo_config_paths())]
    scene_path = demo_scene(quashes[0].encoder, tiny=tiny, seed=seed, cache=quashes[0].cache)
    lmap = quashes[0].read_map(scene_path, adapter="npz")
    if viewer is not None:  # a served or spawned viewer shows the scene while methods run
        viewer.log_map(lmap)
    present = set(lmap.label_names[i] for i in set(lmap.labels.tolist()))
    qs = [q for q in queries if q in present] or None
    # each method is one pass over the map (seconds to half a minute on the full scene):
    # without a line per method, a run on 2 cores said nothing for a minute and more
    with progress(len(quashes), f"evaluating {len(quashes)} methods") as advance:
        report = evaluate(
            lmap,
            quashes,
            queries=qs,
            absent=absent,
            keep_results=viewer is not None,
            on_query=lambda name, n: advance(1),
        )
    if viewer is not None:
        # as quash eval --rrd logs it: one tab per method, each result coloured by outcome
        # against the scene's labels (TP, FP, FN), the evaluation, the best method in view
        viewer.log_report(lmap, report)
    return report, scene_path
