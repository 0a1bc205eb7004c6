"""The classify stage of ``Quash.query`` against the bare float32 GEMM, ratios in one run.

A 400k x 384 map (float32 and float16, ``normalize`` False and True; 1 % zero rows, rows
not unit length) and an ``svm-rbf`` fitted on 64 random "text" rows (one query, 63
negatives), read through ``Quash.query`` with a ``TableEncoder`` (no model needed). The
``classify`` timing of a warm query is compared with ``E32 @ S.T`` (the bare float32
GEMM with the support vectors, numpy's BLAS on every core), timed interleaved with it;
best of ``--reps`` after one warm-up round. The map is read-only: the pass must never
write into it.

``--impls`` compares passes in the same run:

- ``pipeline``: the engine's pass (``quash_plugins.engine.classify.classify_local``);
- ``pipeline+torch``: the same with torch imported (the pass then uses torch's float16
  cast; ``pipeline`` sets ``QUASH_HALF_CAST=numpy``);
- ``previous``: the pass this one replaced, rebuilt here from public pieces: float32
  chunks from ``LatentMap.iter_chunks`` (numpy's cast, an ``isfinite`` pass, norms and a
  divide), then the kernel stack on each chunk.

The issue-13 targets: ``pipeline`` at most 1.3x the GEMM on float32 maps and 1.6x on
float16 maps.

    OMP_NUM_THREADS=2 python benchmarks/bench_classify_stage.py --reps 7
    python benchmarks/bench_classify_stage.py --threads 1 --clock cpu   # a loaded machine
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np


def make_map(n: int, d: int, seed: int = 2) -> np.ndarray:
    rng = np.random.default_rng(seed)
    E = np.empty((n, d), dtype=np.float32)
    for s in range(0, n, 65536):
        b = rng.standard_normal((min(n, s + 65536) - s, d), dtype=np.float32)
        b *= rng.uniform(0.5, 2.0, size=(len(b), 1)).astype(np.float32)  # not unit rows
        E[s : s + len(b)] = b
    E[::97] = 0.0  # unobserved rows
    return E


def build_quash(d: int, seed: int = 1, n_text: int = 64):
    from quash_plugins import Quash, registry
    from quash_plugins.encoders import TableEncoder

    rng = np.random.default_rng(seed)
    words = ["q0"] + [f"neg{i}" for i in range(n_text - 1)]
    T = rng.standard_normal((len(words), d)).astype(np.float32)
    enc = TableEncoder(table={w: T[i] for i, w in enumerate(words)})
    clf = registry.create("classifiers", "svm-rbf", backend="numpy")
    return Quash(enc, classifier=clf, negatives=words[1:], instances=None, device="cpu")


def previous_pass(lmap, classifiers, chunk_bytes, progress=None):
    """The pass before the fused one: prepared float32 chunks, then the stack."""
    from quash_plugins.core.kernels import stack_expansions
    from quash_plugins.engine.classify import extra_bytes_per_row

    rows = lmap.chunk_rows(chunk_bytes, extra_bytes_per_row(classifiers))
    stack, idx = stack_expansions([c.kernel_expansion() for c in classifiers], chunk_bytes)
    out = np.empty((len(classifiers) + 1, lmap.n), np.float32)
    for start, stop, block in lmap.iter_chunks(rows):
        sq = np.einsum("ij,ij->i", block, block)
        out[len(classifiers), start:stop] = sq > 0
        out[idx, start:stop] = stack.evaluate(block, sq=sq).T
    return [out[i] for i in range(len(classifiers))], out[-1] > 0


def impl_fn(name: str):
    from quash_plugins.engine import classify

    if name == "previous":
        return previous_pass
    if name in ("pipeline", "pipeline+torch"):
        cast = "torch" if name == "pipeline+torch" else "numpy"
        if cast == "torch":
            import torch  # noqa: F401  (the pass uses torch's cast once torch is imported)

        def fn(*a, **k):
            os.environ["QUASH_HALF_CAST"] = cast
            return classify.classify_local(*a, **k)

        return fn
    raise SystemExit(f"unknown impl {name!r}; known: pipeline, pipeline+torch, previous")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rows", type=int, default=400_000)
    ap.add_argument("--dim", type=int, default=384)
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--cases", default="f32,f32n,f16,f16n")
    ap.add_argument("--impls", default="pipeline,pipeline+torch,previous")
    ap.add_argument("--text", type=int, default=64, help="text samples (about the SVs)")
    ap.add_argument(
        "--threads",
        type=int,
        default=None,
        help="worker threads of the pass and BLAS threads of the GEMM (default: all cores)",
    )
    ap.add_argument(
        "--clock",
        choices=("wall", "cpu"),
        default="wall",
        help="cpu: process CPU time of the pass (robust to other jobs time-slicing the "
        "cores; use with --threads 1). wall: timings['classify'] of Quash.query",
    )
    args = ap.parse_args()
    if args.threads:
        from threadpoolctl import threadpool_limits

        os.environ["QUASH_CLASSIFY_THREADS"] = str(args.threads)
        threadpool_limits(args.threads)
        if "pipeline+torch" in args.impls:
            import torch

            torch.set_num_threads(args.threads)
    clock = time.process_time if args.clock == "cpu" else time.perf_counter
    from quash_plugins.core.types import LatentMap
    from quash_plugins.engine import pipeline

    q = build_quash(args.dim, n_text=args.text)
    E32 = make_map(args.rows, args.dim)
    E16 = E32.astype(np.float16)
    clf = q.fit(q.expand("q0"))
    S = np.ascontiguousarray(clf.support_vectors_)
    print(
        f"support vectors: {len(S)}; OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS')}; "
        f"threads {args.threads or 'all'}; clock {args.clock}; load {os.getloadavg()}"
    )
    maps = {"f32": (E32, False), "f32n": (E32, True), "f16": (E16, False), "f16n": (E16, True)}
    impls = args.impls.split(",")
    cases = {}
    for c in args.cases.split(","):
        src, norm = maps[c]
        ro = src.view()
        ro.flags.writeable = False  # the pass must never write into the map
        cases[c] = LatentMap(ro, normalize=norm)
    best = {(c, i): float("inf") for c in cases for i in impls}
    gemm = float("inf")
    original = pipeline.classify_local
    try:
        for rep in range(args.reps + 1):  # the first round warms up and is not counted
            for c, lm in cases.items():
                for i in impls:
                    t0 = clock()
                    E32 @ S.T
                    g = clock() - t0
                    fn = impl_fn(i)
                    spent = []

                    def timed(*a, fn=fn, spent=spent, **k):
                        t0 = clock()
                        try:
                            return fn(*a, **k)
                        finally:
                            spent.append(clock() - t0)

                    pipeline.classify_local = timed
                    r = q.query(lm, "q0")
                    if rep:
                        gemm = min(gemm, g)
                        t = r.timings["classify"] if args.clock == "wall" else spent[0]
                        best[c, i] = min(best[c, i], t)
    finally:
        pipeline.classify_local = original
    print(f"bare GEMM E32 @ S.T ({args.rows} x {args.dim} @ {args.dim} x {len(S)}): {gemm:.4f} s")
    print("| map | normalize | " + " | ".join(f"{i} (s) | {i} / GEMM" for i in impls) + " |")
    print("|---|---|" + "---:|---:|" * len(impls))
    for c, lm in cases.items():
        cells = " | ".join(f"{best[c, i]:.4f} | {best[c, i] / gemm:.2f}x" for i in impls)
        print(f"| {lm.dtype} | {lm.normalize} | {cells} |")
    print(platform.platform(), "numpy", np.__version__, "load", os.getloadavg())


if __name__ == "__main__":
    main()
