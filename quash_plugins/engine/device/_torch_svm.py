"""The pass plan on a torch device, and the torch executors (no Triton needed).

:func:`svm_scores_torch` is the fallback of the Triton kernel (and what runs on
``device="cpu"``): chunked, so the ``(rows, S)`` intermediate is bounded by
``chunk_rows``, but it does reach memory, which is why the fused kernel is faster.
:func:`rule_scores_torch` scores every cosine expansion (the ``CosineClassifier``
protocol: ``contrast``, ``nearest-sample``, ``label-argmax``, ``lerf-relevancy``,
``cosine-threshold`` and any plugin's) from one GEMM per chunk.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ._params import LINEAR, RBF, RBF_COS2, RulePlan, SvmPlan, _pow2_scale


@dataclass
class DeviceSvmPlan:
    """:class:`SvmPlan` as tensors on one device (see :mod:`._params` for the math)."""

    VH: Any  # (D, S) float16 hi part
    VL: Any  # (D, S) float16 lo part
    V32: Any  # (D, S) float32
    colscale: Any
    kind: Any
    gamma: Any
    bias: Any
    A: Any  # (S, Q) float32, contiguous
    b: Any  # (Q,)
    S: int
    Q: int
    unit: bool
    has_cos: bool

    @classmethod
    def build(cls, plan: SvmPlan, device: Any) -> DeviceSvmPlan:
        import torch

        hi, lo = plan.halves()

        def t(a: np.ndarray) -> Any:
            return torch.from_numpy(np.ascontiguousarray(a)).to(device)

        return cls(
            VH=t(hi),
            VL=t(lo),
            V32=t(plan.V.astype(np.float32)),
            colscale=t(plan.colscale),
            kind=t(plan.kind),
            gamma=t(plan.gamma),
            bias=t(plan.bias),
            A=t(plan.A),
            b=t(plan.b),
            S=plan.width,
            Q=int(plan.A.shape[1]),
            unit=plan.unit,
            has_cos=plan.has_cos,
        )


def svm_scores_torch(
    x: Any, dp: DeviceSvmPlan, normalize: bool, out: Any, chunk_rows: int = 1 << 16
) -> None:
    """Scores of rows ``x`` ``(n, D)`` into ``out`` ``(Q, n)`` float32, chunk by chunk.

    float16 rows meet ``hi`` and ``lo`` in two float32-accumulated products (as the
    Triton kernel does) on CUDA; elsewhere the chunk is up-cast to float32.
    """
    import torch

    n = x.shape[0]
    for a in range(0, n, chunk_rows):
        xc = x[a : a + chunk_rows]
        xf = xc.float()
        sq = torch.einsum("ij,ij->i", xf, xf)
        c = _products(xc, xf, dp) * dp.colscale
        out[:, a : a + len(xc)] = _epilogue(c, sq, dp, normalize).T


def _products(xc: Any, xf: Any, dp: DeviceSvmPlan) -> Any:
    import torch

    if xc.dtype == torch.float16 and xc.is_cuda and _has_out_dtype():
        # float16 GEMMs would round their result to float16: accumulate into float32
        hi = torch.mm(xc, dp.VH, out_dtype=torch.float32)
        return hi.add_(torch.mm(xc, dp.VL, out_dtype=torch.float32))
    return xf @ dp.V32


_OUT_DTYPE: bool | None = None


def _has_out_dtype() -> bool:
    """``torch.mm(..., out_dtype=torch.float32)`` (torch >= 2.8) on float16 inputs."""
    global _OUT_DTYPE
    if _OUT_DTYPE is None:
        import torch

        try:
            a = torch.zeros((2, 2), dtype=torch.float16, device="cuda")
            _OUT_DTYPE = torch.mm(a, a, out_dtype=torch.float32).dtype == torch.float32
        except (TypeError, RuntimeError):
            _OUT_DTYPE = False
    return _OUT_DTYPE


def _epilogue(c: Any, sq: Any, dp: DeviceSvmPlan, normalize: bool) -> Any:
    import torch

    obs = sq > 0
    inv = torch.where(obs, torch.rsqrt(torch.where(obs, sq, torch.ones_like(sq))), 0.0)
    if normalize:
        z = torch.addcmul(dp.bias - dp.gamma * obs[:, None].float(), c, inv[:, None])
    elif dp.unit:
        z = c + (dp.bias - dp.gamma)
    else:
        z = torch.addcmul(c + dp.bias, sq[:, None], dp.gamma, value=-1.0)
    if dp.has_cos:
        t = c * inv[:, None] if (normalize or not dp.unit) else c
        d = (1.0 - t).clamp_min(0.0)
        zc = -dp.gamma * torch.where(dp.kind == RBF_COS2, d * d, d)
        z = torch.where(dp.kind == RBF, z, zc)
        val = torch.where(dp.kind == LINEAR, t, torch.exp(z))
    else:
        val = torch.exp_(z)
    return torch.addmm(dp.b, val, dp.A)


# ---------------------------------------------------------------------- cosine rules
@dataclass
class DeviceRulePlan:
    L: Any  # (D, L) float32 labels
    LH: Any  # (D, L) float16 hi part of L / colscale
    LL: Any  # (D, L) float16 lo part
    colscale: Any  # (L,) float32 powers of two (keep the halves away from underflow)
    plan: RulePlan

    @classmethod
    def build(cls, plan: RulePlan, device: Any) -> DeviceRulePlan:
        import torch

        scale = _pow2_scale(plan.L.astype(np.float64))
        L64 = plan.L.astype(np.float64) / scale
        hi = L64.astype(np.float16)
        lo = (L64 - hi.astype(np.float64)).astype(np.float16)

        def t(a: np.ndarray) -> Any:
            return torch.from_numpy(np.ascontiguousarray(a)).to(device)

        return cls(t(plan.L), t(hi), t(lo), t(scale.astype(np.float32)), plan)


def rule_scores_torch(
    x: Any,
    dr: DeviceRulePlan,
    outs: list[Any],
    chunk_rows: int = 1 << 16,
) -> None:
    """Scores of every cosine rule for rows ``x``: one ``(rows, L)`` GEMM per chunk
    (float16 rows against the labels' float16 halves, float32 accumulation and output,
    on CUDA: the map is read once, never up-cast), then each rule's reduction on the
    device (:func:`reduce_margin`), or on the host for a rule that declares none.
    ``outs[j]`` is rule ``j``'s ``(n,)`` output."""
    import torch

    n = x.shape[0]
    split = x.dtype == torch.float16 and x.is_cuda and _has_out_dtype()
    for a in range(0, n, chunk_rows):
        xc = x[a : a + chunk_rows]
        if split:
            C = torch.mm(xc, dr.LH, out_dtype=torch.float32)
            C += torch.mm(xc, dr.LL, out_dtype=torch.float32)
            C *= dr.colscale
            sq = torch.linalg.vector_norm(xc, dim=1, dtype=torch.float32).square_()
        else:
            xf = xc.float()
            C = xf @ dr.L
            sq = torch.einsum("ij,ij->i", xf, xf)
        inv = torch.where(sq > 0, torch.rsqrt(torch.where(sq > 0, sq, 1.0)), 0.0)
        C *= inv[:, None]
        for j, ((c0, c1), exp) in enumerate(zip(dr.plan.spans, dr.plan.expansions)):
            c = C[:, c0:c1]
            if exp.margin is not None:
                outs[j][a : a + len(xc)] = reduce_margin(exp.margin, c)
            else:  # a reduction only the classifier's numpy code knows
                host = np.ascontiguousarray(c.cpu().numpy())
                r = np.asarray(exp.reduce(host), dtype=np.float32)
                outs[j][a : a + len(xc)] = torch.from_numpy(r).to(c.device)


def reduce_margin(margin: Any, c: Any) -> Any:
    """A :class:`~quash_plugins.core.kernels.CosineMargin` on torch cosines ``(rows, L)``
    (what :meth:`CosineMargin.apply` does in numpy)."""
    import torch

    p = int(margin.positives)

    def top(m: Any) -> Any:
        k = min(int(margin.k), m.shape[1])
        if k == 1:
            return m.amax(dim=1)
        return m.topk(k, dim=1).values.mean(dim=1)

    r = top(c[:, :p])
    if margin.use_negatives and c.shape[1] > p:
        r = r - top(c[:, p:])
    if margin.temperature is not None:
        z = float(margin.temperature) * r.double()
        r = (0.5 * (1.0 + torch.tanh(0.5 * z))).float()
    return r - float(margin.offset)
