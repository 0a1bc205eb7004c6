"""A fused Triton kernel for stacked kernel-SVM decision functions.

One program scores ``BLOCK_M`` map rows for every stacked classifier:

    for each block of BLOCK_S support columns:
        acc = x @ V[:, cols]            tensor cores, float32 accumulation
        |x|^2 from the same x tiles     (row norm; the observed mask and NaN check)
        z = acc * colscale * r + bias - gamma * q     (RBF; cosine kernels likewise)
        out += exp(z) @ A[cols, :]      (weighted sums of every stacked query)
    out += b; store out (Q, N) and, optionally, |x|^2 (N,)

so the ``(N, S)`` kernel values never reach HBM: the map is read once (per block of
support columns, from L2 after the first), whatever the number of stacked queries.

``MODE`` picks the GEMM: 0 = float16 map, ``V`` split in float16 ``hi + lo`` (two
tensor-core products, float32-accurate); 1 = float16 map, ``V`` in float16 only (one
product, about 2**-11 relative error in ``V``: faster, less exact); 2 = float32 (or
bfloat16, up-cast) map with ``tf32x3`` products (float32-accurate).

The same kernel runs on the CPU under ``TRITON_INTERPRET=1`` (tests).
"""

from __future__ import annotations

import os
from typing import Any

import triton
import triton.language as tl

INTERPRET = os.environ.get("TRITON_INTERPRET", "0") not in ("", "0")


@triton.jit
def _svm_stack_kernel(
    X,
    stride_xm,
    VH,
    VL,
    stride_v,
    COLSCALE,
    KIND,
    GAMMA,
    BIAS,
    A,
    B,
    OUT,
    stride_oq,
    SQ_OUT,
    N,
    D,
    S,
    Q,
    NORMALIZE: tl.constexpr,
    UNIT: tl.constexpr,
    HAS_COS: tl.constexpr,
    MODE: tl.constexpr,
    WRITE_SQ: tl.constexpr,
    BLOCK_M: tl.constexpr,
    BLOCK_S: tl.constexpr,
    BLOCK_K: tl.constexpr,
    BLOCK_Q: tl.constexpr,
):
    pid = tl.program_id(0)
    rows = pid * BLOCK_M + tl.arange(0, BLOCK_M)
    rmask = rows < N
    rows64 = rows.to(tl.int64)  # N * D and Q * N exceed 2**31 on large maps
    offs_k = tl.arange(0, BLOCK_K)
    offs_q = tl.arange(0, BLOCK_Q)
    qmask = offs_q < Q
    out = tl.zeros((BLOCK_M, BLOCK_Q), dtype=tl.float32)
    sq = tl.zeros((BLOCK_M,), dtype=tl.float32)
    for s0 in range(0, S, BLOCK_S):
        cols = s0 + tl.arange(0, BLOCK_S)
        cmask = cols < S
        acc = tl.zeros((BLOCK_M, BLOCK_S), dtype=tl.float32)
        sq = tl.zeros((BLOCK_M,), dtype=tl.float32)
        for k0 in range(0, D, BLOCK_K):
            ks = k0 + offs_k
            kmask = ks < D
            x = tl.load(
                X + rows64[:, None] * stride_xm + ks[None, :],
                mask=rmask[:, None] & kmask[None, :],
                other=0.0,
            )
            xf = x.to(tl.float32)
            sq += tl.sum(xf * xf, axis=1)
            vptr = ks[:, None] * stride_v + cols[None, :]
            vmask = kmask[:, None] & cmask[None, :]
            if MODE == 2:
                v = tl.load(VH + vptr, mask=vmask, other=0.0)
                acc = tl.dot(xf, v, acc, input_precision="tf32x3")
            else:
                xh = x.to(tl.float16)
                vh = tl.load(VH + vptr, mask=vmask, other=0.0)
                acc = tl.dot(xh, vh, acc)
                if MODE == 0:
                    vl = tl.load(VL + vptr, mask=vmask, other=0.0)
                    acc = tl.dot(xh, vl, acc)
        cs = tl.load(COLSCALE + cols, mask=cmask, other=1.0)
        g = tl.load(GAMMA + cols, mask=cmask, other=0.0)
        bias = tl.load(BIAS + cols, mask=cmask, other=0.0)
        c = acc * cs[None, :]
        obs = sq > 0.0
        inv = tl.where(obs, 1.0 / tl.sqrt(tl.where(obs, sq, 1.0)), 0.0)
        if NORMALIZE:
            z = c * inv[:, None] + bias[None, :] - g[None, :] * obs.to(tl.float32)[:, None]
        elif UNIT:
            z = c + bias[None, :] - g[None, :]
        else:
            z = c + bias[None, :] - g[None, :] * sq[:, None]
        if HAS_COS:
            kind = tl.load(KIND + cols, mask=cmask, other=0)
            if NORMALIZE or not UNIT:
                t = c * inv[:, None]
            else:
                t = c
            d = tl.maximum(1.0 - t, 0.0)
            zc = -g[None, :] * tl.where(kind[None, :] == 1, d * d, d)
            z = tl.where(kind[None, :] == 0, z, zc)
            val = tl.exp(z)
            val = tl.where(kind[None, :] == 3, t, val)
        else:
            val = tl.exp(z)
        a = tl.load(
            A + cols[:, None] * Q + offs_q[None, :],
            mask=cmask[:, None] & qmask[None, :],
            other=0.0,
        )
        out = tl.dot(val, a, out, input_precision="ieee")
    bq = tl.load(B + offs_q, mask=qmask, other=0.0)
    out = out + bq[None, :]
    tl.store(
        OUT + offs_q.to(tl.int64)[None, :] * stride_oq + rows64[:, None],
        out,
        mask=rmask[:, None] & qmask[None, :],
    )
    if WRITE_SQ:
        tl.store(SQ_OUT + rows64, sq, mask=rmask)


def _configs() -> list[Any]:
    out = []
    for bm, bs, bk, w, st in (
        (128, 64, 64, 4, 3),
        (128, 64, 64, 8, 3),
        (128, 64, 128, 8, 3),
        (256, 64, 64, 8, 3),
        (64, 64, 64, 4, 4),
        (128, 128, 64, 8, 3),
        (64, 128, 64, 4, 3),
    ):
        out.append(
            triton.Config({"BLOCK_M": bm, "BLOCK_S": bs, "BLOCK_K": bk}, num_warps=w, num_stages=st)
        )
    return out


_TUNED: Any = None


def _tuned() -> Any:
    global _TUNED
    if _TUNED is None:
        _TUNED = triton.autotune(configs=_configs(), key=["D", "S", "Q", "MODE", "NORMALIZE"])(
            _svm_stack_kernel
        )
    return _TUNED


def best_config() -> Any:
    """The autotuned launch configuration (None before the first tuned launch)."""
    return getattr(_TUNED, "best_config", None)


def launch(
    x: Any,
    dplan: Any,
    normalize: bool,
    out: Any,
    sq_out: Any = None,
    mode: int | None = None,
    blocks: tuple[int, int, int] | None = None,
) -> None:
    """Scores of the rows ``x`` ``(n, D)`` (device tensor, rows contiguous) into
    ``out`` ``(Q, n)`` float32, and ``|x|^2`` into ``sq_out`` ``(n,)`` when given.

    ``dplan`` is a :class:`~quash_plugins.engine.device.DeviceSvmPlan` on ``x``'s
    device. ``blocks = (BLOCK_M, BLOCK_S, BLOCK_K)`` skips autotuning (the interpreter
    always uses small fixed blocks).
    """
    import torch

    n, d = x.shape
    if n == 0:
        return
    if x.stride(1) != 1:
        x = x.contiguous()
    if mode is None:
        mode = 0 if x.dtype == torch.float16 else 2
    if mode == 2 and x.dtype not in (torch.float32, torch.bfloat16):
        x = x.float()
    if mode in (0, 1) and x.dtype != torch.float16:
        raise ValueError("modes 0 and 1 take float16 rows")
    vh, vl = (dplan.V32, dplan.V32) if mode == 2 else (dplan.VH, dplan.VL)
    q = dplan.Q
    block_q = max(16, triton.next_power_of_2(q))
    write_sq = sq_out is not None
    sq_arg = sq_out if write_sq else out
    args = (
        x, x.stride(0), vh, vl, vh.stride(0),
        dplan.colscale, dplan.kind, dplan.gamma, dplan.bias, dplan.A, dplan.b,
        out, out.stride(0), sq_arg, n, d, dplan.S, q,
    )  # fmt: skip
    meta = dict(
        NORMALIZE=bool(normalize),
        UNIT=bool(dplan.unit),
        HAS_COS=bool(dplan.has_cos),
        MODE=int(mode),
        WRITE_SQ=write_sq,
        BLOCK_Q=block_q,
    )
    if INTERPRET or blocks is not None:
        bm, bs, bk = blocks or (32, 16, 16)
        grid = (triton.cdiv(n, bm),)
        _svm_stack_kernel[grid](*args, **meta, BLOCK_M=bm, BLOCK_S=bs, BLOCK_K=bk)
        return
    kern = _tuned()
    kern[lambda m: (triton.cdiv(n, m["BLOCK_M"]),)](*args, **meta)
