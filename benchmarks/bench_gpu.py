"""GPU inference speed: every path against reading the map once, measured in one run.

Needs one CUDA GPU, torch and Triton (a stock CUDA torch image) and the project on
``PYTHONPATH``; nothing else. The rows that import the package's pipeline (the old torch
back end, ``contrast`` on the device, the end-to-end ``Quash.query`` and the check
against ``SVC.decision_function``) need scikit-learn and PyYAML too (the package imports
them); without them those rows say "skipped". Meant to run in well under three minutes
on an H100/H200 with the defaults (not yet run on a GPU: see docs/benchmarks.md)::

    PYTHONPATH=. python benchmarks/bench_gpu.py            # 1e7 x 512 float16
    PYTHONPATH=. python benchmarks/bench_gpu.py --rows 2e6 --no-autotune   # quick look

The map (``--rows`` x ``--dim`` float16, unit-ish rows, 1 % zero rows) is generated on
the device. The SVMs are synthetic fitted RBF SVMs (``--sv`` support vectors, random
dual coefficients, gamma 1): the speed of the decision function does not depend on how
they were fitted. Times are medians of ``--reps`` CUDA-event timings after warm-up.

Rows (the issue's table):

- map read: half a device-to-device copy of the map (read + write);
- cosine mat-vec ``E @ q`` (what a threshold rule costs);
- a plain torch loop: chunked float16 GEMM, float32 exp, mat-vec;
- the old torch back end, ``KernelStack(backend="torch", device="cuda")`` on the map;
- the fused Triton kernel, one query (``mode 0``: float32-accurate split products, the
  default; ``mode 1``: single float16 products) and 8 stacked queries (per query);
- the torch fallback of the fused pass (``svm_scores_torch``);
- ``contrast`` (a cosine rule) on the device: one GEMM and the reduction;
- ``Quash.query`` end to end on a map already on the device (``LatentMap(TensorRows)``),
  wall time and its ``classify`` stage;
- a host map larger than wished on the device, streamed through pinned double buffers,
  against one pinned host-to-device copy of it.
"""

from __future__ import annotations

import argparse
import math
import platform
import time
from types import SimpleNamespace

import numpy as np
import torch


def sync() -> None:
    if torch.cuda.is_available():
        torch.cuda.synchronize()


def cuda_ms(fn, reps: int, warm: int = 2) -> float:
    """Median milliseconds of ``fn`` over ``reps`` runs (CUDA events)."""
    if not torch.cuda.is_available():  # --device cpu: a dry run of the script
        return wall_ms(fn, reps, warm)
    for _ in range(warm):
        fn()
    torch.cuda.synchronize()
    times = []
    for _ in range(reps):
        a, b = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
        a.record()
        fn()
        b.record()
        b.synchronize()
        times.append(a.elapsed_time(b))
    return float(np.median(times))


def wall_ms(fn, reps: int, warm: int = 1) -> float:
    for _ in range(warm):
        fn()
    times = []
    for _ in range(reps):
        sync()
        t0 = time.perf_counter()
        fn()
        sync()
        times.append((time.perf_counter() - t0) * 1e3)
    return float(np.median(times))


def make_map(n: int, d: int, dev: torch.device, seed: int = 0) -> torch.Tensor:
    g = torch.Generator(device=dev).manual_seed(seed)
    emb = torch.empty((n, d), dtype=torch.float16, device=dev)
    step = 1 << 20
    for a in range(0, n, step):
        b = min(n, a + step)
        x = torch.randn((b - a, d), generator=g, device=dev)
        x *= torch.empty((b - a, 1), device=dev).uniform_(0.5, 2.0, generator=g) / math.sqrt(d)
        emb[a:b] = x.half()
    emb[::97] = 0
    return emb


def synthetic_parts(q: int, s: int, d: int, seed: int = 1) -> list:
    from quash_plugins.core.kernels import KernelPart

    rng = np.random.default_rng(seed)
    parts = []
    for _ in range(q):
        sv = rng.standard_normal((s, d)).astype(np.float32)
        sv /= np.linalg.norm(sv, axis=1, keepdims=True)
        parts.append(KernelPart("rbf", sv, rng.uniform(-1, 1, s), -0.3, 1.0))
    return parts


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rows", type=float, default=1e7)
    ap.add_argument("--dim", type=int, default=512)
    ap.add_argument("--sv", type=int, default=64)
    ap.add_argument("--stack", type=int, default=8)
    ap.add_argument("--reps", type=int, default=10)
    ap.add_argument("--host-rows", type=float, default=2e6, help="rows of the streamed map")
    ap.add_argument("--no-autotune", action="store_true", help="fixed kernel blocks")
    ap.add_argument("--check-rows", type=int, default=200_000)
    ap.add_argument(
        "--device",
        default="cuda",
        help="cpu: a dry run of this script at small sizes (with TRITON_INTERPRET=1)",
    )
    args = ap.parse_args()

    import triton

    from quash_plugins.engine.device import (
        DeviceMap,
        DeviceSvmPlan,
        TensorRows,
        best_config,
        launch,
        reference_scores,
        stream_chunks,
        svm_plan_from_parts,
        svm_scores_torch,
    )

    t_start = time.perf_counter()
    dev = torch.device(args.device)
    cuda = dev.type == "cuda"
    n, d = int(args.rows), args.dim
    emb = make_map(n, d, dev)
    gb = emb.numel() * 2 / 1e9
    parts = synthetic_parts(args.stack, args.sv, d)
    plan1 = svm_plan_from_parts(parts[:1])
    plan8 = svm_plan_from_parts(parts)
    dp1, dp8 = DeviceSvmPlan.build(plan1, dev), DeviceSvmPlan.build(plan8, dev)
    blocks = (128, 64, 64) if args.no_autotune else None
    rows: list[tuple[str, float | None, str]] = []

    # ---------------------------------------------------------------- floors
    tmp = {"dst": torch.empty_like(emb)}
    t_read = cuda_ms(lambda: tmp["dst"].copy_(emb), args.reps) / 2
    tmp.clear()
    if cuda:
        torch.cuda.empty_cache()
    rows.append(("map read (half a device-to-device copy)", t_read, ""))
    qv = torch.randn(d, device=dev).half()
    rows.append(("cosine mat-vec `E @ q`", cuda_ms(lambda: emb @ qv, args.reps), ""))

    # ---------------------------------------------------------------- plain torch loop
    p = parts[0]
    V16 = torch.from_numpy((2 * p.gamma * p.vectors).T.copy()).half().to(dev)
    bias = torch.from_numpy(-p.gamma * (p.vectors**2).sum(1)).float().to(dev)
    coef = torch.from_numpy(p.coef).float().to(dev)
    dmap = DeviceMap(SimpleNamespace(
        n=n, dim=d, normalize=False, source={}, dtype=np.float16, embeddings=TensorRows(emb)
    ), dev)  # fmt: skip
    sq = dmap.sq
    out_plain = torch.empty(n, device=dev)

    def plain() -> None:
        step = 1 << 20
        for a in range(0, n, step):
            G = (emb[a : a + step] @ V16).float()
            G += bias
            G -= p.gamma * sq[a : a + step, None]
            out_plain[a : a + step] = G.exp_() @ coef + p.intercept

    rows.append(("plain torch loop (chunked GEMM, exp, mat-vec)", cuda_ms(plain, args.reps), ""))

    # ---------------------------------------------------------------- old torch back end
    try:
        from quash_plugins.core.kernels import KernelPart, KernelStack

        kp = KernelPart("rbf", p.vectors, p.coef, p.intercept, p.gamma)
        old = KernelStack([kp], "torch", dev.type)
        t_old = wall_ms(lambda: old.evaluate(emb), max(2, args.reps // 4))
        rows.append(('old `KernelStack(backend="torch", device="cuda")` (to host)', t_old, ""))
    except ImportError as exc:
        rows.append(("old torch back end", None, f"skipped: {exc}"))

    # ---------------------------------------------------------------- fused kernel
    out1 = torch.empty((1, n), device=dev)
    out8 = torch.empty((args.stack, n), device=dev)
    if cuda:
        torch.cuda.reset_peak_memory_stats()
    base = torch.cuda.memory_allocated() if cuda else 0
    t_f0 = cuda_ms(lambda: launch(emb, dp1, False, out1, mode=0, blocks=blocks), args.reps)
    peak_extra = (torch.cuda.max_memory_allocated() - base) / 2**20 if cuda else float("nan")
    cfg0 = best_config()
    t_f1 = cuda_ms(lambda: launch(emb, dp1, False, out1, mode=1, blocks=blocks), args.reps)
    t_f8 = cuda_ms(lambda: launch(emb, dp8, False, out8, mode=0, blocks=blocks), args.reps)
    rows.append(
        (
            "fused Triton kernel, 1 query (mode 0, float32-accurate)",
            t_f0,
            f"extra peak {peak_extra:.0f} MiB; {cfg0}",
        )
    )
    rows.append(("fused Triton kernel, 1 query (mode 1, float16 V)", t_f1, ""))
    rows.append(
        (
            f"fused Triton kernel, {args.stack} stacked queries, per query",
            t_f8 / args.stack,
            f"{t_f8:.2f} ms in all",
        )
    )
    t_tf = cuda_ms(
        lambda: svm_scores_torch(emb, dp1, False, out1, chunk_rows=1 << 20), max(2, args.reps // 2)
    )
    rows.append(("torch fallback of the fused pass, 1 query", t_tf, "chunks of 2**20 rows"))

    # ---------------------------------------------------------------- accuracy
    m = min(n, args.check_rows)
    xs = emb[:m].float().cpu().numpy().astype(np.float64)
    ref1 = reference_scores(plan1, xs, False)[:, 0]
    ref8 = reference_scores(plan8, xs, False)
    notes = []
    for mode in (0, 1):
        launch(emb[:m], dp1, False, out1[:, :m], mode=mode, blocks=blocks)
        notes.append(f"mode {mode}: {np.abs(out1[0, :m].cpu().numpy() - ref1).max():.1e}")
    launch(emb[:m], dp8, False, out8[:, :m], mode=0, blocks=blocks)
    notes.append(f"{args.stack} stacked: {np.abs(out8[:, :m].cpu().numpy().T - ref8).max():.1e}")
    notes.append(f"plain loop: {np.abs(out_plain[:m].cpu().numpy() - ref1).max():.1e}")
    acc_line = f"max |diff| against the float64 definition on {m} rows: " + ", ".join(notes)

    # ---------------------------------------------------------------- end to end
    e2e_note = ""
    t_e2e = None
    try:
        from quash_plugins import Quash, registry
        from quash_plugins.core.types import LatentMap
        from quash_plugins.encoders import TableEncoder
        from quash_plugins.engine import device as device_pkg

        rng = np.random.default_rng(3)
        words = ["q0"] + [f"neg{i}" for i in range(args.sv - 1)]
        T = rng.standard_normal((len(words), d)).astype(np.float32)
        enc = TableEncoder(table={w: T[i] for i, w in enumerate(words)})
        q = Quash(
            enc,
            classifier=registry.create("classifiers", "svm-rbf", backend="numpy"),
            negatives=words[1:],
            instances=None,
            device=dev.type,
        )
        contrast = registry.create("classifiers", "contrast").fit(T[:4], np.array([1, 0, 0, 0]))
        drp = device_pkg.DeviceRulePlan.build(device_pkg.build_plan([contrast]).rules, dev)
        outr = torch.empty(n, device=dev)
        t_rule = cuda_ms(lambda: device_pkg.rule_scores_torch(emb, drp, [outr]), args.reps)
        rows.append(
            ("`contrast` (1 positive, 3 negatives) on the device", t_rule, "torch GEMM + reduction")
        )
        lmap = LatentMap(TensorRows(emb))
        if not cuda:  # the dry run: route the pipeline's pass to the CPU device
            device_pkg.pass_device = lambda device: "cpu"
        device_pkg.device_map(lmap, dev.type)  # adopts the tensor: no copy; kept for Quash
        res = {}

        def query() -> None:
            res["r"] = q.query(lmap, "q0")

        t_e2e = wall_ms(query, max(3, args.reps // 2))
        t_cls = res["r"].timings["classify"] * 1e3
        rows.append(("`Quash.query` end to end, map on the device (wall)", t_e2e, ""))
        rows.append(
            ("`Quash.query`: its classify stage", t_cls, f"{t_cls / t_f0:.2f}x the fused kernel")
        )
        clf = q.fit(q.expand("q0"))
        sk = clf.svc_.decision_function(xs[:20000])
        mine = res["r"].scores[:20000]
        obs = (xs[:20000] ** 2).sum(1) > 0
        err = np.abs(mine[obs] - sk[obs]).max()
        e2e_note = f"`Quash.query` scores vs scikit-learn on 20000 rows: {err:.1e}"
    except ImportError as exc:
        rows.append(("`Quash.query` end to end", None, f"skipped: {exc}"))

    # ---------------------------------------------------------------- streamed host map
    hn = min(n, int(args.host_rows))
    host = emb[:hn].cpu().numpy()
    tmp = {
        "pinned": torch.empty((hn, d), dtype=torch.float16, pin_memory=cuda),
        "dst": torch.empty((hn, d), dtype=torch.float16, device=dev),
    }
    tmp["pinned"].numpy()[:] = host
    t_h2d = cuda_ms(lambda: tmp["dst"].copy_(tmp["pinned"], non_blocking=True), 3, warm=1)
    tmp.clear()
    hmap = SimpleNamespace(
        n=hn, dim=d, normalize=False, source={}, dtype=np.float16, embeddings=host
    )
    outh = torch.empty((1, hn), device=dev)

    def streamed() -> None:
        for a, b, x in stream_chunks(hmap, 1 << 18, dev):
            launch(x, dp1, False, outh[:, a:b], mode=0, blocks=blocks)
        outh.cpu()

    t_st = wall_ms(streamed, 3)
    rows.append(
        (
            f"streamed host map {hn:.0e} x {d} float16, 1 query (wall, to host)",
            t_st,
            f"one pinned H2D copy of it: {t_h2d:.1f} ms",
        )
    )

    # ---------------------------------------------------------------- report
    name = torch.cuda.get_device_name() if cuda else "CPU dry run"
    print(
        f"\n{name} | torch {torch.__version__} | triton {triton.__version__}"
        f" | {platform.python_version()} | map {n:.0e} x {d} float16 ({gb:.1f} GB) | {args.sv} support vectors\n"
    )
    print("| path | time (ms) | vs map read | note |")
    print("|---|---:|---:|---|")
    for name, t, note in rows:
        if t is None:
            print(f"| {name} | - | - | {note} |")
        else:
            print(f"| {name} | {t:.2f} | {t / t_read:.2f}x | {note} |")
    print()
    print(acc_line)
    if e2e_note:
        print(e2e_note)
    e2e = f"; Quash.query {t_e2e / t_f0:.2f}x the kernel (<= 1.2)" if t_e2e else ""
    print(
        f"targets: 1 query {t_f0 / t_read:.2f}x the read (<= 1.3), "
        f"{args.stack} stacked {t_f8 / args.stack / t_read:.2f}x per query (<= 0.8){e2e}"
    )
    print(f"total bench time {time.perf_counter() - t_start:.0f} s")


if __name__ == "__main__":
    main()
