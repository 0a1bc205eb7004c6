"""What text evidence gives on the proxy scenes when the segmentation is perfect.

Every method of the quality benchmark labels the map from text alone: the map's items are
compared with the text embeddings of names. This benchmark asks what the best such
decision could reach if it knew the map's true objects. Each object instance of a scene
(``make_scene``'s instance ids: no method sees them) is read by the mean of its items,
centred as the presence check centres (the map's mean unit row off the region mean, the
names' mean off the names), and given the label whose names score highest; with a
``margin``, an object whose best label wins by less than that gets no label. Every
label's mask is then the union of its objects, scored like the quality benchmark's closed
vocabulary (the present labels as queries, the taxonomy's absent labels as absence
queries, with the same label list: the map's labels and the absent ones, each with its
sub-classes).

It is a reference for what an object-level reading of the text gives, not a strict
bound: one margin serves every object here, while the presence check judges regions by
several tests (its grown region, its core, the label that wins its support), so on a hard
table it can keep more objects at the same absence (b-hard: recall 0.35 for QuASH
against 0.25-0.31 here at absence 1.0). The margin at which an absent label first wins
an object shows how far apart present and absent objects sit. Readings of a label's
names (``--readings``): ``top2`` (the mean of the two best of the label and its
sub-classes: QuASH's presence check), ``top1`` (the best name), ``label`` (the label name
alone) and ``mean`` (the normalised mean of the names). The table gives each, so the best
can be read off after the fact (an optimistic reference).

Re-run with::

    .venv/bin/python benchmarks/bench_ceiling.py --out bench-ceiling --seeds 0,1,2,3,4

(``--generators`` and ``--classes FILE.yaml`` as in ``bench_quality.py``). Scenes are
built in memory (a few seconds each, names from the text cache). It writes
``DIR/ceiling.md`` and ``DIR/ceiling.json``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from bench_quality import GENERATORS, named_generators, parse_seeds, with_classes

from quash_plugins.core import registry
from quash_plugins.core.text import encode_texts
from quash_plugins.demo.scene import SceneOptions, make_scene
from quash_plugins.engine import open_cache
from quash_plugins.evaluation.metrics import query_metrics

READINGS = ("top2", "top1", "label", "mean")
MARGINS = (0.0, 0.02, 0.05, 0.1)
GENERIC = ("other", "background", "nothing")


def _unit(a: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(a, axis=-1, keepdims=True)
    return a / np.where(n > 0, n, 1.0)


def group_scores(means: np.ndarray, groups: list[np.ndarray], reading: str) -> np.ndarray:
    """``(objects, groups)`` scores of centred object means against centred name rows."""
    cols = []
    for rows in groups:
        c = means @ rows.T
        if reading == "top2":
            k = min(2, c.shape[1])
            cols.append(np.sort(c, axis=1)[:, -k:].mean(axis=1))
        elif reading == "top1":
            cols.append(c.max(axis=1))
        elif reading == "label":
            cols.append(c[:, 0])
        else:
            cols.append(means @ _unit(rows.mean(axis=0)))
    return np.stack(cols, axis=1)


def one_scene(gen: str, seed: int, encoder, cache) -> dict:
    """Every reading and margin on one scene: F1, recall and absence, and the margins."""
    scene = make_scene(encoder, SceneOptions(seed=seed, **GENERATORS[gen]), cache)
    lmap = scene.map
    E = _unit(np.asarray(lmap.embeddings, np.float32))
    labels, names = np.asarray(lmap.labels), list(lmap.label_names)
    labs = list(scene.taxonomy)  # the map's labels and the absent ones, with sub-classes
    texts = [[lab, *scene.taxonomy[lab]] for lab in labs] + [list(GENERIC)]
    rows = [encode_texts(encoder, t, cache) for t in texts]
    centre = np.concatenate(rows).mean(axis=0)
    groups = [_unit(r - centre) for r in rows]
    inst = np.unique(scene.instance_ids, return_inverse=True)[1]
    n_inst = int(inst.max()) + 1
    sums = np.zeros((n_inst, E.shape[1]), np.float64)
    np.add.at(sums, inst, E)
    sizes = np.bincount(inst, minlength=n_inst)
    means = _unit((sums / sizes[:, None]).astype(np.float32) - E.mean(axis=0))
    truth_of = np.array([np.bincount(labels[inst == i]).argmax() for i in range(n_inst)])
    present = [lab for lab in labs if lab in names and np.any(labels == names.index(lab))]
    absent = [lab for lab in labs if lab not in present]
    out: dict = {"generator": gen, "seed": seed, "objects": n_inst, "readings": {}}
    for reading in READINGS:
        S = group_scores(means, groups, reading)
        best = S.argmax(axis=1)
        top2 = np.sort(S, axis=1)[:, -2:]
        won_by = top2[:, 1] - top2[:, 0]
        # the last group is the generic negatives: an object there has no label
        right = np.array([b < len(labs) and labs[b] == names[t] for b, t in zip(best, truth_of)])
        # how far each absent label's best object wins (> 0: it takes that object)
        absent_best = []
        for lab in absent:
            j = labs.index(lab)
            absent_best.append(float((S[:, j] - np.delete(S, j, axis=1).max(axis=1)).max()))
        rec = {
            "object_accuracy": float(right.mean()),
            "item_accuracy": float((right * sizes).sum() / sizes.sum()),
            "absent_best_margin": max(absent_best) if absent_best else None,
            "margins": {},
        }
        for margin in MARGINS:
            given = np.where(won_by >= margin, best, -1)[inst]
            f1s, recs = [], []
            for lab in present:
                m = query_metrics(given == labs.index(lab), labels == names.index(lab))
                f1s.append(m["f1"])
                recs.append(m["recall"])
            empty = [not np.any(given == labs.index(lab)) for lab in absent]
            rec["margins"][str(margin)] = {
                "f1": float(np.mean(f1s)),
                "recall": float(np.mean(recs)),
                "absence": float(np.mean(empty)) if empty else None,
                "present_empty": int(sum(r == 0 for r in recs)),
                "n_present": len(present),
                "n_absent": len(absent),
            }
        out["readings"][reading] = rec
    return out


def summary(recs: list[dict]) -> list[str]:
    """The markdown table: per generator, reading and margin, means over seeds."""
    lines = [
        "| generator | reading | margin | F1 | recall | absence | present -> empty "
        "| object accuracy | absent labels' best margin (max over seeds) |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for gen in dict.fromkeys(r["generator"] for r in recs):
        mine = [r for r in recs if r["generator"] == gen]
        for reading in READINGS:
            acc = np.mean([r["readings"][reading]["object_accuracy"] for r in mine])
            worst = max(r["readings"][reading]["absent_best_margin"] or -1.0 for r in mine)
            for margin in MARGINS:
                ms = [r["readings"][reading]["margins"][str(margin)] for r in mine]
                ab = [m["absence"] for m in ms if m["absence"] is not None]
                lines.append(
                    f"| {gen} | {reading} | {margin} | {np.mean([m['f1'] for m in ms]):.3f} | "
                    f"{np.mean([m['recall'] for m in ms]):.3f} | "
                    f"{np.mean(ab) if ab else float('nan'):.3f} | "
                    f"{sum(m['present_empty'] for m in ms)}/{sum(m['n_present'] for m in ms)} "
                    f"| {acc:.3f} | {worst:+.3f} |"
                )
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="bench-ceiling", help="output folder (default: %(default)s)")
    ap.add_argument("--seeds", default="0,1,2,3,4", help="scene seeds (default: %(default)s)")
    ap.add_argument("--generators", default=None, help=f"of {', '.join(GENERATORS)} (default: all)")
    ap.add_argument(
        "--classes",
        default=None,
        metavar="FILE.yaml",
        help="run table A's generators on this class-table file instead",
    )
    args = ap.parse_args()
    out = Path(args.out)
    gens = named_generators(args.generators, args.classes)
    unknown = [g for g in gens if g not in GENERATORS]
    if unknown:
        raise SystemExit(f"unknown generator: {unknown[0]} (of {', '.join(GENERATORS)})")
    if args.classes:
        gens = with_classes(gens, Path(args.classes))
    seeds = parse_seeds(args.seeds)
    out.mkdir(parents=True, exist_ok=True)  # after the checks: a refused run leaves nothing
    encoder = registry.create("encoders", "minilm")
    cache = open_cache(True)
    recs = []
    for gen in gens:
        for seed in seeds:
            t = time.perf_counter()
            recs.append(one_scene(gen, seed, encoder, cache))
            print(f"{gen} seed {seed}: {time.perf_counter() - t:.1f} s", flush=True)
    md = [
        f"# quash bench-ceiling: seeds {', '.join(map(str, seeds))}",
        "",
        "Each true object labelled by its mean's best label (no label when it wins by less "
        "than the margin); closed vocabulary, the label list of bench_quality.py.",
        "",
        *summary(recs),
        "",
    ]
    (out / "ceiling.md").write_text("\n".join(md), encoding="utf-8")
    (out / "ceiling.json").write_text(json.dumps(recs) + "\n", encoding="utf-8")
    print("\n".join(md))


if __name__ == "__main__":
    main()
