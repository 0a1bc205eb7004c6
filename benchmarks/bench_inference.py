"""Inference speed of the fitted SVMs against scikit-learn and the hardware floors.

For each map size ``N x D`` (unit float32 rows) an RBF SVM is fitted on 64 random unit
"text" embeddings (about 60 support vectors) and its decision function is timed:

- ``ours``: :meth:`RbfSvmClassifier.decision_function` (numpy back end, norms computed);
- ``ours unit``: the same with ``unit_rows=True`` (no norm pass);
- ``torch cpu``: the torch back end on the CPU;
- ``sklearn``: ``SVC.decision_function`` (timed on a subsample when N is large, scaled
  linearly to N, and marked so);
- ``E @ S.T``: the bare float32 GEMM with the support vectors (compute floor);
- ``E @ q``: one cosine mat-vec (the memory floor the cosine baselines pay).

Peak extra memory during one query is measured with tracemalloc (numpy reports its
buffers to it), less the ``(N,)`` output, and compared with the block working set.

Run::

    nice python benchmarks/bench_inference.py --out /tmp/inference.md
"""

from __future__ import annotations

import argparse
import os
import platform
import time
import tracemalloc

import numpy as np

from quash_plugins.classifiers import RbfSvmClassifier


def best_of(f, reps: int) -> float:
    best = float("inf")
    for _ in range(reps):
        t0 = time.perf_counter()
        f()
        best = min(best, time.perf_counter() - t0)
    return best


def unit_map(n: int, d: int, seed: int, dtype=np.float32) -> np.ndarray:
    rng = np.random.default_rng(seed)
    E = np.empty((n, d), dtype=dtype)
    for s in range(0, n, 65536):
        b = rng.standard_normal((min(n, s + 65536) - s, d), dtype=np.float32)
        b /= np.linalg.norm(b, axis=1, keepdims=True)
        E[s : s + len(b)] = b
    return E


def peak_extra(f, out_bytes: int) -> int:
    tracemalloc.start()
    tracemalloc.reset_peak()
    base = tracemalloc.get_traced_memory()[0]
    f()
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return max(0, peak - base - out_bytes)


def run(n: int, d: int, reps: int, sk_rows: int, torch_ok: bool) -> dict:
    rng = np.random.default_rng(1)
    X = rng.standard_normal((64, d)).astype(np.float32)
    X /= np.linalg.norm(X, axis=1, keepdims=True)
    y = (np.arange(64) < 16).astype(int)
    clf = RbfSvmClassifier(backend="numpy").fit(X, y)
    clf_unit = RbfSvmClassifier(backend="numpy", unit_rows=True).fit(X, y)
    E = unit_map(n, d, seed=2)
    S = clf.support_vectors_
    q = X[0]
    clf.decision_function(E[:10000])
    row = {"N": n, "D": d, "n_sv": len(S)}
    row["ours"] = best_of(lambda: clf.decision_function(E), reps)
    row["ours_unit"] = best_of(lambda: clf_unit.decision_function(E), reps)
    row["gemm"] = best_of(lambda: E @ S.T, reps)
    row["matvec"] = best_of(lambda: E @ q, reps)
    if torch_ok:
        clf_t = RbfSvmClassifier(backend="torch", device="cpu").fit(X, y)
        clf_t.decision_function(E[:10000])
        row["torch"] = best_of(lambda: clf_t.decision_function(E), reps)
    m = min(n, sk_rows)
    sub = E[:m]
    t_sk = best_of(lambda: clf.svc_.decision_function(sub), 1)
    row["sklearn"] = t_sk * n / m
    row["sk_sub"] = m < n
    diff = np.abs(clf.decision_function(sub) - clf.svc_.decision_function(sub)).max()
    row["maxdiff"] = float(diff)
    row["peak_mb"] = peak_extra(lambda: clf.decision_function(E), 4 * n) / 2**20
    st = clf.stack_
    row["block_rows"] = st.block_rows
    # the block working set the classifier sizes its blocks by: float32 rows (a view for
    # float32 input, the up-cast copy for float16), the (rows, n_sv) kernel, the output
    row["ws_mb"] = st.block_rows * (4 * d + 4 * st.width + 4 + 8) / 2**20
    if n >= 10**6 and d == 512:
        qs = [RbfSvmClassifier(backend="numpy").fit(X, np.roll(y, 16 * k)) for k in range(4)]
        from quash_plugins.core.kernels import stack_expansions

        stack, _ = stack_expansions([c.kernel_expansion() for c in qs])
        row["multi4"] = best_of(lambda: stack.evaluate(E), reps) / 4
        E16 = E.astype(np.float16)
        row["fp16"] = best_of(lambda: clf.decision_function(E16), reps)
        row["fp16_peak_mb"] = peak_extra(lambda: clf.decision_function(E16), 4 * n) / 2**20
        del E16
    return row


def table(rows: list[dict]) -> str:
    lines = [
        "| N | D | SVs | ours (s) | ours, unit rows (s) | torch CPU (s) | sklearn (s) "
        "| sklearn / ours | ours / `E @ S.T` | ours / `E @ q` | max abs diff "
        "| peak extra MB (block working set MB) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        sk = f"{r['sklearn']:.2f}" + (" (sub)" if r["sk_sub"] else "")
        tt = f"{r['torch']:.3f}" if "torch" in r else "-"
        lines.append(
            f"| {r['N']:.0e} | {r['D']} | {r['n_sv']} | {r['ours']:.3f} | {r['ours_unit']:.3f} "
            f"| {tt} | {sk} | {r['sklearn'] / r['ours']:.0f}x | {r['ours'] / r['gemm']:.2f} "
            f"| {r['ours'] / r['matvec']:.1f} | {r['maxdiff']:.1e} "
            f"| {r['peak_mb']:.1f} ({r['ws_mb']:.1f}) |"
        )
    extra = [r for r in rows if "multi4" in r]
    for r in extra:
        lines += [
            "",
            f"N = {r['N']:.0e}, D = {r['D']}: four queries stacked into one pass "
            f"(`query_many`): {r['multi4']:.3f} s per query (one query alone: "
            f"{r['ours']:.3f} s). A float16 map (up-cast block by block): {r['fp16']:.3f} s, "
            f"peak extra {r['fp16_peak_mb']:.1f} MB.",
        ]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", default="1e5x512,1e5x1024,1e6x512,1e6x1024")
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument(
        "--sklearn-rows",
        type=int,
        default=100_000,
        help="subsample scikit-learn to this many rows and scale linearly",
    )
    ap.add_argument("--no-torch", action="store_true")
    ap.add_argument("--out", default=None, help="write the Markdown table here")
    ap.add_argument(
        "--threads",
        type=int,
        default=None,
        help="BLAS/torch threads (default: the libraries' own, i.e. all cores)",
    )
    args = ap.parse_args()
    if args.threads:
        from threadpoolctl import threadpool_limits

        threadpool_limits(args.threads)
    torch_ok = not args.no_torch
    if torch_ok:
        try:
            import torch

            if args.threads:
                torch.set_num_threads(args.threads)
        except ImportError:
            torch_ok = False
    rows = []
    for spec in args.sizes.split(","):
        n, d = spec.lower().split("x")
        rows.append(run(int(float(n)), int(d), args.reps, args.sklearn_rows, torch_ok))
        print(rows[-1], flush=True)
    md = table(rows)
    host = f"{platform.machine()}, {os.cpu_count()} CPU cores, numpy {np.__version__}"
    host += f", threads {args.threads or 'default'}"
    md += f"\n\nMachine: {host}; {platform.platform()}."
    print(md)
    if args.out:
        with open(args.out, "w") as fh:
            fh.write(md + "\n")


if __name__ == "__main__":
    main()
