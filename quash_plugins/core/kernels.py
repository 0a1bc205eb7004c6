"""Fast evaluation of fitted kernel SVMs: chunked float32 GEMMs, numpy or torch.

A fitted SVM's decision function is ``f(x) = sum_i a_i k(x, s_i) + b``. Every kernel
here is a function of the dot products ``x . s_i`` and the squared norm ``|x|^2``:

- ``rbf``: ``exp(-g |x - s|^2) = exp(2g x.s - g|s|^2 - g|x|^2)``;
- ``rbf-cosine``: ``exp(-g d^p)`` with ``d = 1 - x.s_hat / |x|`` (``p`` 1 or 2);
- ``linear-cosine``: ``x.s_hat / |x|``, folded into one vector ``w = sum_i a_i s_hat_i``.

So one block of map rows costs one GEMM against the (pre-scaled) support vectors, a few
in-place passes over the small ``(rows, n_support)`` result (bias, exp) and one small
GEMM with the dual coefficients. Several fitted classifiers are *stacked*: their
support vectors become the columns of one GEMM and their coefficients a block-diagonal
matrix, so ``query_many`` reads the map once (:class:`KernelStack`).

Blocks are sized by a working-set budget and, on the CPU, kept cache-sized so the
passes after the GEMM hit cache. Float16 input is up-cast block by block.

The engine's fused pass over a map (``quash_plugins.engine.classify.BlockScorer``) uses
the same stack through :meth:`KernelStack.epilogue`, next to the cosine rules'
:class:`CosineExpansion` columns, and the CPU helpers of :mod:`quash_plugins.core.cpu`
(``half_to_float``, ``blas_single_thread``, ``cpu_threads``).

What a classifier declares (:class:`KernelPart`, :class:`KernelExpansion`,
:class:`CosineExpansion`, :class:`CosineMargin`) lives in
:mod:`quash_plugins.core.expansions`, and is re-exported here.
"""

from __future__ import annotations

import logging
import os
import sys
from collections.abc import Sequence
from typing import Any

import numpy as np

from .cpu import blas_single_thread, cpu_threads, sq_norms
from .errors import QuashError
from .expansions import (
    KINDS,
    CosineExpansion,
    CosineMargin,
    KernelExpansion,
    KernelPart,
    reference_kernel,
    top_mean,
)

# the declarations live in core/expansions.py; these names stay importable from here
__all__ = [
    "CPU_BLOCK_BYTES",
    "FOLD_LIMIT",
    "KINDS",
    "CosineExpansion",
    "CosineMargin",
    "KernelExpansion",
    "KernelPart",
    "KernelStack",
    "StackEpilogue",
    "kernel_values_",
    "reference_kernel",
    "resolve_backend",
    "stack_expansions",
    "top_mean",
]

log = logging.getLogger(__name__)

#: CPU blocks target this many bytes of float32 rows (fits the last-level cache).
CPU_BLOCK_BYTES = 16 * 2**20


def stack_expansions(
    expansions: Sequence[KernelExpansion | None], working_set_bytes: int = 256 * 2**20
) -> tuple[KernelStack | None, list[int]]:
    """One :class:`KernelStack` for the expansions given (``None`` entries are skipped).

    Returns the stack (``None`` when nothing qualifies) and the indices of the
    expansions it evaluates, in output-column order. Only expansions that share the
    backend, device and ``unit_rows`` of the first are stacked; the caller evaluates the
    others on their own.
    """
    idx = [i for i, e in enumerate(expansions) if e is not None]
    if not idx:
        return None, []
    first = expansions[idx[0]]
    key = (first.backend, first.device, first.unit_rows)
    idx = [i for i in idx if (e := expansions[i]) and (e.backend, e.device, e.unit_rows) == key]
    stack = KernelStack([expansions[i].part for i in idx], key[0], key[1], working_set_bytes)
    stack.unit = key[2]
    return stack, idx


def resolve_backend(backend: str, device: str) -> tuple[str, str]:
    """Pick ``(backend, device)``. ``auto`` means torch on a visible CUDA GPU, else numpy.

    torch is imported only when it is asked for, or when ``auto`` sees an NVIDIA device
    node (``/dev/nvidiactl``) so that CPU-only runs never pay torch's import time.
    ``cuda:N`` picks one GPU; ``mps`` means the CPU here (there is no Apple-GPU path).
    """
    if device == "mps":
        device = "cpu"
    cuda_asked = device.split(":")[0] == "cuda"
    if backend == "numpy":
        if device not in ("auto", "cpu"):
            raise QuashError(f"Backend 'numpy' runs on the CPU only; got device {device!r}.")
        return "numpy", "cpu"
    want_torch = (
        backend == "torch"
        or cuda_asked
        or (backend == "auto" and ("torch" in sys.modules or os.path.exists("/dev/nvidiactl")))
    )
    if not want_torch:
        return "numpy", "cpu"
    try:
        import torch
    except ImportError as exc:
        if backend == "auto" and device == "auto":
            return "numpy", "cpu"
        raise QuashError(
            'Classifier backend "torch" needs PyTorch: pip install "quash-plugins[clip]".'
        ) from exc
    cuda = torch.cuda.is_available()
    if cuda_asked and not cuda:
        raise QuashError(f"Classifier device {device!r} was asked for but no CUDA GPU is visible.")
    if backend == "auto" and device == "auto" and not cuda:
        return "numpy", "cpu"
    return "torch", (device if cuda_asked else "cuda" if (device == "auto" and cuda) else "cpu")


def kernel_values_(G: np.ndarray, cos_segments: Any, n_exp: int) -> np.ndarray:
    """Turn the exponents of a block's kernel columns into kernel values, in place.

    ``G`` holds, per column, ``-gamma |x - s|^2`` (RBF parts, the first ``n_exp``
    columns) or the cosine (cosine parts); each cosine segment ``(a, b, gamma, p)``
    becomes ``-gamma max(0, 1 - cos)^p``, then the first ``n_exp`` columns are
    exponentiated. Shared by :class:`KernelStack` and the fused block epilogue.
    """
    for a, b, g, p in cos_segments:
        seg = G[:, a:b]
        np.subtract(1.0, seg, out=seg)
        np.maximum(seg, 0.0, out=seg)
        if p == 2:
            np.square(seg, out=seg)
        seg *= -g
    if n_exp:
        head = G[:, :n_exp]
        np.exp(head, out=head)
    return G


class KernelStack:
    """Several fitted kernel decision functions evaluated with one GEMM per block.

    Parameters
    ----------
    parts
        The decision functions; output column ``j`` is ``parts[j]``.
    backend, device
        Already resolved (see :func:`resolve_backend`).
    working_set_bytes
        Budget for one block's float32 rows plus its ``(rows, width)`` intermediate.
    block_rows
        Rows per block; ``None`` picks cache-sized blocks on the CPU and the whole
        budget on a GPU.
    """

    def __init__(
        self,
        parts: Sequence[KernelPart],
        backend: str = "numpy",
        device: str = "cpu",
        working_set_bytes: int = 256 * 2**20,
        block_rows: int | None = None,
    ) -> None:
        if not parts:
            raise ValueError("KernelStack needs at least one fitted part.")
        order = sorted(range(len(parts)), key=lambda j: KINDS.index(parts[j].kind))
        self.parts = list(parts)
        self.backend, self.device = backend, device
        self.dim = int(parts[0].vectors.shape[1])
        vecs, bias, grbf, coef_rows = [], [], [], []
        self.cos_segments: list[tuple[int, int, float, int]] = []
        col = 0
        self.n_exp = 0
        for j in order:
            p = parts[j]
            v = np.asarray(p.vectors, dtype=np.float64)
            if p.kind == "rbf":
                vecs.append(2.0 * p.gamma * v)
                bias.append(-p.gamma * np.einsum("ij,ij->i", v, v))
                grbf.append(np.full(len(v), p.gamma))
                self.n_exp = col + len(v)
            else:
                vecs.append(v)
                bias.append(np.zeros(len(v)))
                grbf.append(np.zeros(len(v)))
                if p.kind == "rbf-cosine":
                    self.cos_segments.append((col, col + len(v), p.gamma, p.power))
                    self.n_exp = col + len(v)
            coef_rows.append((j, col, np.asarray(p.coef, dtype=np.float64)))
            col += len(v)
        self.width = col
        self.has_cos = any(parts[j].kind != "rbf" for j in order)
        self.has_rbf = any(parts[j].kind == "rbf" for j in order)
        gammas = {parts[j].gamma for j in order if parts[j].kind == "rbf"}
        only_rbf = all(parts[j].kind == "rbf" for j in order)
        self.one_gamma = np.float32(gammas.pop()) if only_rbf and len(gammas) == 1 else None
        A = np.zeros((col, len(parts)))
        for j, c0, coef in coef_rows:
            A[c0 : c0 + len(coef), j] = coef
        V = np.concatenate(vecs).astype(np.float32)
        self._np = {
            "Vt": np.ascontiguousarray(V.T),
            "bias": np.concatenate(bias).astype(np.float32),
            "grbf": np.concatenate(grbf).astype(np.float32),
            "A": A.astype(np.float32),
            "b": np.array([p.intercept for p in parts], dtype=np.float32),
        }
        per_row = 4 * self.dim + 4 * self.width + 4 * len(parts) + 8
        budget_rows = max(1, int(working_set_bytes) // per_row)
        self.budget_rows = budget_rows
        if block_rows is None:
            if device == "cuda":
                block_rows = budget_rows
            else:
                block_rows = min(budget_rows, max(256, CPU_BLOCK_BYTES // (4 * self.dim)))
        self.block_rows = max(1, min(int(block_rows), budget_rows))
        self._torch: dict[str, Any] | None = None

    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        state["_torch"] = None  # device tensors and the module are rebuilt on first use
        return state

    @property
    def columns(self) -> np.ndarray:
        """``(D, width)`` float32 right-hand side of the stacked GEMM ``x @ columns``."""
        return self._np["Vt"]

    def epilogue(self, normalize: bool, unit: bool = False) -> StackEpilogue:
        """The steps after the GEMM for rows that are (``normalize``) or are not
        normalised when read, or known to be unit (``unit``); see :class:`StackEpilogue`."""
        return StackEpilogue(self, normalize, unit)

    # ------------------------------------------------------------------ numpy
    def _numpy_block(self, x: np.ndarray, sq: np.ndarray | None, G: np.ndarray) -> np.ndarray:
        t = self._np
        np.matmul(x, t["Vt"], out=G)
        G += t["bias"]
        if self.has_rbf and sq is not None:
            if self.one_gamma is not None:  # broadcast a column: no (rows, S) temporary
                G -= (self.one_gamma * sq)[:, None]
            else:
                G -= np.multiply.outer(sq, t["grbf"])
        elif self.has_rbf:
            G -= t["grbf"]
        if self.has_cos:
            inv = _inv_norm(sq, len(x))
            G[:, self._cos_start :] *= inv[:, None]
        kernel_values_(G, self.cos_segments, self.n_exp)
        out = G @ t["A"]
        out += t["b"]
        return out

    @property
    def _cos_start(self) -> int:
        if self.cos_segments:
            return self.cos_segments[0][0]
        return int(self.width - sum(1 for p in self.parts if p.kind == "linear-cosine"))

    # ------------------------------------------------------------------ torch
    def _torch_state(self) -> dict[str, Any]:
        if self._torch is None:
            import torch

            dev = torch.device(self.device)
            self._torch = {k: torch.from_numpy(v).to(dev) for k, v in self._np.items()}
            self._torch["torch"] = torch
        return self._torch

    def _torch_block(self, x: Any, sq: Any) -> Any:
        t = self._torch_state()
        torch = t["torch"]
        G = torch.addmm(t["bias"], x, t["Vt"])
        if self.has_rbf and sq is not None:
            G.addr_(sq, t["grbf"], alpha=-1.0)
        elif self.has_rbf:
            G.sub_(t["grbf"])
        if self.has_cos:
            if sq is None:
                inv = torch.ones(len(x), device=x.device)
            else:
                inv = torch.where(sq > 0, sq.clamp_min(1e-30).rsqrt(), torch.zeros_like(sq))
            G[:, self._cos_start :].mul_(inv[:, None])
        for a, b, g, p in self.cos_segments:
            seg = G[:, a:b]
            seg.neg_().add_(1.0).clamp_(min=0.0)
            if p == 2:
                seg.square_()
            seg.mul_(-g)
        if self.n_exp:
            G[:, : self.n_exp].exp_()
        return torch.addmm(t["b"], G, t["A"])

    # ------------------------------------------------------------------ public
    def evaluate(self, E: Any, sq: np.ndarray | None = None, unit: bool = False) -> np.ndarray:
        """Decision values ``(N, len(parts))`` float32 for rows ``E`` ``(N, D)``.

        Parameters
        ----------
        E
            Any array-like sliceable by rows (numpy, memmap, h5py, torch); any float dtype.
        sq
            ``(N,)`` squared row norms when the caller has them already.
        unit
            Rows are known to be L2-unit: skip the norms (zero rows then score like
            unit rows; the pipeline masks them anyway).
        """
        n = len(E)
        out = np.empty((n, len(self.parts)), dtype=np.float32)
        if n == 0:
            return out
        if self.backend == "torch":
            return self._evaluate_torch(E, sq, unit, out)
        rows = self.block_rows
        workers = min(cpu_threads(), -(-n // rows)) if isinstance(E, np.ndarray) else 1
        # the working-set budget holds for all workers together
        rows = max(1, min(rows, self.budget_rows // max(1, workers)))
        starts = list(range(0, n, rows))
        if workers <= 1:
            self._numpy_range(E, sq, unit, out, starts, rows)
            return out
        # One single-threaded BLAS per worker on its own blocks: no per-call thread sync,
        # which on a busy machine costs more than the GEMM itself (numpy releases the GIL).
        from concurrent.futures import ThreadPoolExecutor

        with blas_single_thread(), ThreadPoolExecutor(workers) as pool:
            jobs = [
                pool.submit(self._numpy_range, E, sq, unit, out, starts[k::workers], rows)
                for k in range(workers)
            ]
            for job in jobs:
                job.result()
        return out

    def _numpy_range(
        self, E: Any, sq: Any, unit: bool, out: np.ndarray, starts: Sequence[int], rows: int
    ) -> None:
        n = len(E)
        G = np.empty((min(rows, n), self.width), dtype=np.float32)
        # non-float32 input (float16 maps, h5py datasets) is cast into one reused buffer
        cast = getattr(E, "dtype", None) != np.float32 or not isinstance(E, np.ndarray)
        buf = np.empty((min(rows, n), self.dim), dtype=np.float32) if cast else None
        for start in starts:
            stop = min(n, start + rows)
            if buf is not None:
                x = buf[: stop - start]
                x[...] = E[start:stop]
            else:
                x = E[start:stop]
            if unit:
                s = None
            elif sq is not None:
                s = np.asarray(sq[start:stop], dtype=np.float32)
            else:
                s = sq_norms(x)
            out[start:stop] = self._numpy_block(x, s, G[: stop - start])

    def _evaluate_torch(self, E: Any, sq: Any, unit: bool, out: np.ndarray) -> np.ndarray:
        t = self._torch_state()
        torch = t["torch"]
        dev = torch.device(self.device)
        rows = self.block_rows
        with torch.inference_mode():
            for start in range(0, len(E), rows):
                stop = min(len(E), start + rows)
                blk = E[start:stop]
                if not isinstance(blk, torch.Tensor):
                    blk = torch.from_numpy(np.ascontiguousarray(blk))
                x = blk.to(dev, non_blocking=True).to(torch.float32)
                if unit:
                    s = None
                elif sq is not None:
                    s = torch.as_tensor(np.asarray(sq[start:stop], np.float32), device=dev)
                else:
                    s = torch.einsum("ij,ij->i", x, x)
                out[start:stop] = self._torch_block(x, s).cpu().numpy()
        return out


#: ``exp(-g|s|^2)`` is folded into the dual coefficients while ``g|s|^2`` stays below this.
FOLD_LIMIT = 60.0


class StackEpilogue:
    """What follows the GEMM ``G = x @ stack.columns`` on one block of raw map rows.

    The rows are never normalised: ``x/|x| . v = (x . v) / |x|``, so a map read with
    ``normalize`` has ``G`` scaled by ``1/|x|`` (``W`` columns, not ``D``), and ``|x|^2``
    is then 1, which moves ``-g`` into the bias. Otherwise one pass subtracts
    ``g |x|^2`` from the RBF columns. The RBF constant ``exp(-g|s|^2)`` is folded into
    the dual coefficients (``exp(a + bias) = exp(a) exp(bias)``) when ``-bias`` is at most
    :data:`FOLD_LIMIT`: the exponent left, ``g (|s|^2 - |x - s|^2)``, is then at most
    ``-bias`` as well, so nothing overflows. What remains is one scaling pass, one ``exp``
    and one small GEMM with the coefficients.

    Parameters
    ----------
    stack
        The fitted stack.
    normalize
        The map's rows are L2-normalised when read.
    unit
        The rows are known to be unit (``unit_rows``): ``|x|^2`` taken as 1.
    """

    def __init__(self, stack: KernelStack, normalize: bool, unit: bool = False) -> None:
        self.stack = stack
        self.normalize = bool(normalize)
        self.unit = bool(unit)
        t = stack._np
        A = t["A"].astype(np.float64)
        bias = t["bias"].astype(np.float64)
        grbf = t["grbf"].astype(np.float64)
        self.rbf_segments: list[tuple[int, int, float]] = []
        col = 0  # rbf parts come first in the stack, in their own order
        for p in stack.parts:
            if p.kind == "rbf":
                self.rbf_segments.append((col, col + p.width, float(p.gamma)))
                col += p.width
        self.n_rbf = n_rbf = col
        self.cos_start = stack._cos_start if stack.has_cos else stack.width
        self.scale_all = self.normalize  # G *= 1/|x| over every column
        self.sq_pass = not (self.normalize or self.unit)  # G_rbf -= g |x|^2
        self.cos_scale = stack.has_cos and not (self.normalize or self.unit)
        rbf_bias = bias[:n_rbf] - (0.0 if self.sq_pass else grbf[:n_rbf])
        self.fold = bool(n_rbf) and bool(np.all(-rbf_bias <= FOLD_LIMIT))
        if self.fold:
            A[:n_rbf] *= np.exp(rbf_bias)[:, None]
            self.bias_rbf = None
        else:
            self.bias_rbf = rbf_bias.astype(np.float32)
        self.A = A.astype(np.float32)
        self.b = t["b"]
        # an all-zero row keeps the scores the stack gives it (unobserved rows are masked)
        self.zero_scores = stack._numpy_block(
            np.zeros((1, stack.dim), np.float32),
            None if self.unit else np.zeros(1, np.float32),
            np.empty((1, stack.width), np.float32),
        )[0]

    @property
    def needs_inv(self) -> bool:
        """Whether :meth:`apply` reads ``1/|x|``."""
        return self.scale_all or self.cos_scale

    def apply(
        self, G: np.ndarray, sq: np.ndarray, inv: np.ndarray | None, obs: np.ndarray
    ) -> np.ndarray:
        """Decision values ``(rows, Q)`` float32 from ``G`` ``(rows, width)`` (overwritten).

        ``sq`` are the rows' squared norms, ``inv`` ``1/|x|`` (0 for zero rows; needed
        when :attr:`needs_inv`), ``obs`` ``sq > 0``.
        """
        st = self.stack
        if self.scale_all:
            G *= inv[:, None]
        if self.sq_pass:
            if len(self.rbf_segments) == 1:
                G[:, : self.n_rbf] -= (np.float32(self.rbf_segments[0][2]) * sq)[:, None]
            else:
                for a, b, g in self.rbf_segments:
                    G[:, a:b] -= (np.float32(g) * sq)[:, None]
        if self.bias_rbf is not None:
            G[:, : self.n_rbf] += self.bias_rbf
        if self.cos_scale:
            G[:, self.cos_start :] *= inv[:, None]
        kernel_values_(G, st.cos_segments, st.n_exp)
        R = G @ self.A
        R += self.b
        if self.normalize and not obs.all():
            R[~obs] = self.zero_scores
        return R


def _inv_norm(sq: np.ndarray | None, n: int) -> np.ndarray:
    if sq is None:
        return np.ones(n, dtype=np.float32)
    inv = np.zeros_like(sq, dtype=np.float32)
    np.sqrt(sq, out=inv, where=sq > 0)
    np.divide(1.0, inv, out=inv, where=inv > 0)
    return inv
