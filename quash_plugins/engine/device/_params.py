"""The device-independent plan of one fused pass: stacked SVM columns and cosine rules.

Pure numpy (no torch): built once per pass from the fitted classifiers, then uploaded
by the torch or Triton executors. Column ``j`` of the stacked GEMM ``x @ V`` holds

- ``rbf``: ``V_j = 2 g s_j`` (scaled by a power of two, see ``colscale``); the exponent
  is ``c r + bias_j - g q`` with ``(r, q) = (1/|x|, 1)`` on a normalised map and
  ``(1, |x|^2)`` otherwise, ``bias_j = -g |s_j|^2``;
- ``rbf-cosine``: ``V_j = s_j / |s_j|``; ``t = c / |x|``, exponent ``-g max(1 - t, 0)^p``;
- ``linear-cosine``: ``V_j = w``; the value is ``t = c / |x|`` itself (no exp).

The value of every column is weighted by ``A (S, Q)`` and ``b (Q,)`` is added: one
output column per stacked classifier.

float16 maps meet the support vectors in a float16 tensor-core GEMM with float32
accumulation. A float16 copy of ``V`` alone would round each entry by up to 2**-11
(relative), an error the exponent multiplies by ``2 g |x| |s|``; so ``V`` is split into
``hi = fp16(V)`` and ``lo = fp16(V - hi)`` and both products are accumulated (the map's
float16 values are exact, so the result is float32-accurate). ``colscale`` keeps every
column of ``V`` near 1 before the split (powers of two, exact), so neither part
underflows float16.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

RBF, RBF_COS2, RBF_COS1, LINEAR = 0, 1, 2, 3


@dataclass
class SvmPlan:
    """Stacked SVM columns, in the order of ``KernelStack`` (rbf, rbf-cosine, linear)."""

    indices: list[int]  # classifier index of each output column
    V: np.ndarray  # (D, S) float64, divided by colscale
    colscale: np.ndarray  # (S,) float32 powers of two
    kind: np.ndarray  # (S,) int32
    gamma: np.ndarray  # (S,) float32
    bias: np.ndarray  # (S,) float32
    A: np.ndarray  # (S, Q) float32
    b: np.ndarray  # (Q,) float32
    unit: bool  # unit_rows: |x|^2 taken as 1 (unnormalised maps)

    @property
    def width(self) -> int:
        return int(self.V.shape[1])

    @property
    def has_cos(self) -> bool:
        return bool(np.any(self.kind != RBF))

    def halves(self) -> tuple[np.ndarray, np.ndarray]:
        """``(hi, lo)`` float16 ``(D, S)`` with ``hi + lo == V`` to about 2**-22."""
        hi = self.V.astype(np.float16)
        lo = (self.V - hi.astype(np.float64)).astype(np.float16)
        return hi, lo


@dataclass
class RulePlan:
    """Cosine expansions: their label columns side by side; each reduces its own."""

    indices: list[int]  # classifier index of each rule
    L: np.ndarray  # (D, L) float32 label vectors of every rule, stacked
    spans: list[tuple[int, int]] = field(default_factory=list)  # columns of each rule
    expansions: list[Any] = field(default_factory=list)  # the CosineExpansion of each


@dataclass
class PassPlan:
    svm: SvmPlan | None
    rules: RulePlan | None
    others: list[int]
    dim: int


def _pow2_scale(V: np.ndarray) -> np.ndarray:
    m = np.abs(V).max(axis=0)
    e = np.where(m > 0, np.floor(np.log2(np.where(m > 0, m, 1.0))), 0.0)
    return np.exp2(e)


def build_plan(classifiers: list[Any]) -> PassPlan:
    """Plan the fused pass of fitted ``classifiers``, through the optional protocols:
    every kernel expansion (``StackableClassifier``) with the ``unit_rows`` of the first
    is stacked, whatever back end it was fitted for; every cosine expansion
    (``CosineClassifier``) is a rule; the rest are ``others``."""
    from ..classify import cosine_expansions, kernel_expansions

    kexp = kernel_expansions(classifiers)
    svm_idx = [i for i, e in enumerate(kexp) if e is not None]
    if svm_idx:
        unit = bool(kexp[svm_idx[0]].unit_rows)
        svm_idx = [i for i in svm_idx if bool(kexp[i].unit_rows) == unit]
    svm = None
    if svm_idx:
        svm = svm_plan_from_parts([kexp[i].part for i in svm_idx], unit)
        svm.indices = list(svm_idx)
    rule_idx, labels, spans, exps, col = [], [], [], [], 0
    for i, e in enumerate(cosine_expansions(classifiers)):
        if e is None or i in svm_idx:
            continue
        rule_idx.append(i)
        labels.append(np.asarray(e.labels, np.float32))
        spans.append((col, col + e.width))
        exps.append(e)
        col += e.width
    rules = (
        RulePlan(rule_idx, np.ascontiguousarray(np.concatenate(labels).T), spans, exps)
        if rule_idx
        else None
    )
    done = set(svm_idx) | set(rule_idx)
    others = [i for i in range(len(classifiers)) if i not in done]
    dim = svm.V.shape[0] if svm is not None else (rules.L.shape[0] if rules else 0)
    return PassPlan(svm, rules, others, int(dim))


def svm_plan_from_parts(parts: list[Any], unit: bool = False) -> SvmPlan:
    """The plan of fitted :class:`~quash_plugins.core.kernels.KernelPart` s (output
    column ``j`` is ``parts[j]``)."""
    kinds = ("rbf", "rbf-cosine", "linear-cosine")
    order = sorted(range(len(parts)), key=lambda j: kinds.index(parts[j].kind))
    cols, kind, gamma, bias, coef = [], [], [], [], []
    for j in order:
        p = parts[j]
        v = np.asarray(p.vectors, np.float64)
        if p.kind == "rbf":
            cols.append(2.0 * p.gamma * v)
            bias.append(-p.gamma * np.einsum("ij,ij->i", v, v))
            kind.append(np.full(len(v), RBF))
        else:
            cols.append(v)
            bias.append(np.zeros(len(v)))
            code = LINEAR if p.kind == "linear-cosine" else (RBF_COS2 if p.power == 2 else RBF_COS1)
            kind.append(np.full(len(v), code))
        gamma.append(np.full(len(v), p.gamma))
        coef.append((j, np.asarray(p.coef, np.float64)))
    V = np.concatenate(cols).T  # (D, S)
    S = V.shape[1]
    A = np.zeros((S, len(parts)))
    c0 = 0
    for j, cf in coef:
        A[c0 : c0 + len(cf), j] = cf
        c0 += len(cf)
    scale = _pow2_scale(V)
    return SvmPlan(
        indices=list(range(len(parts))),
        V=V / scale,
        colscale=scale.astype(np.float32),
        kind=np.concatenate(kind).astype(np.int32),
        gamma=np.concatenate(gamma).astype(np.float32),
        bias=np.concatenate(bias).astype(np.float32),
        A=A.astype(np.float32),
        b=np.array([p.intercept for p in parts], np.float32),
        unit=bool(unit),
    )


def reference_scores(plan: SvmPlan, x: np.ndarray, normalize: bool) -> np.ndarray:
    """``(N, Q)`` float64 decision values of the plan, straight from its definition
    (the oracle for the executors' tests)."""
    x = np.asarray(x, np.float64)
    sq = np.einsum("ij,ij->i", x, x)
    obs = sq > 0
    inv = np.divide(1.0, np.sqrt(sq), out=np.zeros_like(sq), where=obs)
    c = (x @ plan.V) * plan.colscale.astype(np.float64)
    if normalize:
        r, q = inv, obs.astype(np.float64)
    elif plan.unit:
        r, q = np.ones_like(sq), np.ones_like(sq)
    else:
        r, q = np.ones_like(sq), sq
    g = plan.gamma.astype(np.float64)
    z_rbf = c * r[:, None] + plan.bias - g * q[:, None]
    t = c * (inv if (normalize or not plan.unit) else np.ones_like(sq))[:, None]
    d = np.maximum(1.0 - t, 0.0)
    z_cos = -g * np.where(plan.kind == RBF_COS2, d * d, d)
    val = np.where(plan.kind == RBF, np.exp(z_rbf), np.exp(z_cos))
    val = np.where(plan.kind == LINEAR, t, val)
    return val @ plan.A.astype(np.float64) + plan.b
