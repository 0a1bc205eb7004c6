"""Scale-out on Dask: classification throughput against workers and the in-memory path.

Generates a zarr map of ``--rows`` rows x ``--dim`` float16 (streamed, never whole in
memory), fits ``contrast`` for two queries and times the classification pass:

- numpy backend, embeddings in RAM (the in-memory reference);
- numpy backend, embeddings read from the zarr store chunk by chunk;
- dask backend on a LocalCluster with 1, 2 and 4 worker processes (1 thread each).

Every dask result is checked against the reference (masks equal, scores within 1e-5).

Usage::

    nice .venv/bin/python benchmarks/bench_dask.py --rows 4000000 --dim 64 --out /tmp/bench
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from pathlib import Path

import numpy as np

WORDS = ["chair", "sofa", "table", "other", "background", "nothing"]


def make_map(path: Path, rows: int, dim: int, seed: int = 0):
    """Stream a clustered, un-normalised float16 map with 1% zero rows into ``path``."""
    import dask.array as da

    from quash_plugins.adapters import write_zarr_map
    from quash_plugins.core.types import LatentMap

    rng = np.random.default_rng(seed)
    T = rng.normal(size=(len(WORDS), dim)).astype(np.float32)
    T /= np.linalg.norm(T, axis=1, keepdims=True)
    step = 500_000

    def block(block_info=None):
        lo, hi = block_info[None]["array-location"][0]
        r = np.random.default_rng(seed + 1 + lo)
        lab = r.integers(0, 3, size=hi - lo)
        e = T[lab] + 0.7 * r.normal(size=(hi - lo, dim)).astype(np.float32)
        e *= r.uniform(0.5, 3.0, size=(hi - lo, 1)).astype(np.float32)
        e[r.random(hi - lo) < 0.01] = 0
        return e.astype(np.float16)

    chunks = ((step,) * (rows // step) + ((rows % step,) if rows % step else ()), (dim,))
    emb = da.map_blocks(block, chunks=chunks, dtype=np.float16, meta=np.empty((0, 0), np.float16))
    lmap = LatentMap(emb, normalize=True)
    write_zarr_map(lmap, path, chunk_mb=16)
    return {w: T[i].tolist() for i, w in enumerate(WORDS)}


def timed(fn, repeat: int):
    best, out = float("inf"), None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=4_000_000)
    ap.add_argument("--dim", type=int, default=64)
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2, 4])
    ap.add_argument("--chunk-mb", type=float, default=64.0)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--out", type=Path, default=Path("/tmp/quash-bench-dask"))
    args = ap.parse_args()

    import distributed

    from quash_plugins import Quash
    from quash_plugins.adapters import read_map
    from quash_plugins.core import registry
    from quash_plugins.core.types import LatentMap
    from quash_plugins.encoders import TableEncoder

    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / f"map-{args.rows}x{args.dim}.zarr"
    t = time.perf_counter()
    table = make_map(path, args.rows, args.dim)
    t_write = time.perf_counter() - t
    texts = ["chair", "sofa"]
    clf = registry.create("classifiers", "contrast")

    def quash(**kw):
        return Quash(
            TableEncoder(table=table), classifier=clf, instances=None, chunk_mb=args.chunk_mb, **kw
        )

    zmap = read_map(path)
    ram = LatentMap(np.asarray(zmap.embeddings[...]), normalize=True)
    rows = []
    sec, ref = timed(lambda: quash().query_many(ram, texts), args.repeat)
    rows.append(("numpy, embeddings in RAM (reference)", sec))
    sec, _ = timed(lambda: quash().query_many(zmap, texts), args.repeat)
    rows.append(("numpy, read from zarr", sec))
    for n in args.workers:
        with (
            distributed.LocalCluster(
                n_workers=n,
                threads_per_worker=1,
                processes=True,
                host="127.0.0.1",
                dashboard_address="127.0.0.1:0",
            ) as cluster,
            distributed.Client(cluster) as client,
        ):
            q = quash(backend="dask", client=client)
            q.query_many(read_map(path), texts[:1])  # warm the workers' imports
            sec, res = timed(lambda q=q: q.query_many(read_map(path), texts), args.repeat)
            for r, e in zip(res, ref):
                assert np.array_equal(r.mask, e.mask)
                assert np.abs(r.scores - e.scores).max() <= 1e-5
        rows.append((f"dask LocalCluster, {n} worker process{'es' if n > 1 else ''}", sec))

    size_gb = args.rows * args.dim * 2 / 1e9
    print(
        f"map: {args.rows} rows x {args.dim} float16 ({size_gb:.2f} GB), zarr written in "
        f"{t_write:.1f} s; 2 queries (contrast), chunk_mb {args.chunk_mb}; best of "
        f"{args.repeat}"
    )
    print(
        f"machine: {platform.machine()}, {os.cpu_count()} cores "
        f"(affinity {len(os.sched_getaffinity(0))}), {platform.python_version()}, "
        f"load average {os.getloadavg()[0]:.1f}"
    )
    print()
    print("| path | seconds | million rows/s | vs in-memory |")
    print("|---|---:|---:|---:|")
    base = rows[0][1]
    for name, sec in rows:
        print(f"| {name} | {sec:.2f} | {args.rows / sec / 1e6:.2f} | {base / sec:.2f}x |")
    print("\nall dask results equal the in-memory ones (masks equal, scores within 1e-5)")


if __name__ == "__main__":
    main()
