"""What a fitted classifier declares so that the engine can evaluate it with others in
one pass over the map, with no ``isinstance`` check on any class:

- a :class:`KernelExpansion` (one :class:`KernelPart`: ``sum_i coef_i k(x, s_i) + b``
  with an ``rbf``, ``rbf-cosine`` or ``linear-cosine`` kernel), returned by
  :meth:`StackableClassifier.kernel_expansion
  <quash_plugins.core.interfaces.StackableClassifier>`;
- a :class:`CosineExpansion` (cosines with fixed vectors and a reduction of them, as a
  :class:`CosineMargin` where it is one), returned by
  :meth:`CosineClassifier.cosine_expansion
  <quash_plugins.core.interfaces.CosineClassifier>`.

Plain data and numpy only: a plugin that declares an expansion imports nothing of the
evaluation (:mod:`quash_plugins.core.kernels`, which runs them; it re-exports these
names).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

#: The kernels a :class:`KernelPart` may have.
KINDS = ("rbf", "rbf-cosine", "linear-cosine")


@dataclass
class KernelPart:
    """One fitted decision function ``sum_i coef_i k(x, vectors_i) + intercept``.

    ``vectors`` is ``(S, D)`` float32: raw support vectors for ``rbf``, unit ones for
    ``rbf-cosine``, and the single folded weight vector for ``linear-cosine``.
    """

    kind: str
    vectors: np.ndarray
    coef: np.ndarray
    intercept: float
    gamma: float = 1.0
    power: int = 2

    @property
    def width(self) -> int:
        return int(len(self.vectors))


@dataclass(frozen=True)
class KernelExpansion:
    """A fitted classifier's decision function as a kernel part, and where it runs.

    Returned by :meth:`StackableClassifier.kernel_expansion
    <quash_plugins.core.interfaces.StackableClassifier>`; the engine stacks the
    expansions of several queries into one GEMM per block.

    Attributes
    ----------
    part
        The decision function ``sum_i coef_i k(x, vectors_i) + intercept``.
    backend, device
        Resolved backend (``"numpy"`` or ``"torch"``) and device (``"cpu"``, ``"cuda"``).
    unit_rows
        True when the classifier may assume unit-norm input rows.
    """

    part: KernelPart
    backend: str = "numpy"
    device: str = "cpu"
    unit_rows: bool = False


def top_mean(c: np.ndarray, k: int) -> np.ndarray:
    """Row-wise mean of the ``k`` largest values of ``c`` ``(N, m)``, ``k`` capped at ``m``.

    The reduction of every cosine rule (:class:`CosineMargin`, ``nearest-sample``) and of
    the presence check's readings, in one place.

    >>> top_mean(np.array([[0.1, 0.9, 0.5], [0.3, 0.2, 0.4]]), 2).round(2).tolist()
    [0.7, 0.35]
    """
    k = min(int(k), c.shape[1])
    if k <= 1:
        return c.max(axis=1)
    return np.partition(c, c.shape[1] - k, axis=1)[:, -k:].mean(axis=1)


@dataclass(frozen=True)
class CosineMargin:
    """A cosine rule's reduction, declared so that any executor can run it (a GPU too).

    With ``c`` the ``(rows, L)`` cosines of :class:`CosineExpansion` and ``p`` =
    :attr:`positives`::

        m = mean of the k largest of c[:, :p]  -  mean of the k largest of c[:, p:]
        decision = link(m) - offset

    The second term is left out when :attr:`use_negatives` is False (or there are no
    negative columns). ``link`` is the identity, or with :attr:`temperature` ``T`` the
    logistic ``0.5 * (1 + tanh(0.5 * T * m))`` (a two-way softmax), computed in float64.
    ``k`` is capped by each side's number of columns.
    """

    positives: int
    k: int = 1
    use_negatives: bool = True
    temperature: float | None = None
    offset: float = 0.0

    def apply(self, c: np.ndarray) -> np.ndarray:
        """The reduction in numpy: ``(rows,)`` float32 (the reference for executors)."""
        p = int(self.positives)
        m = top_mean(c[:, :p], self.k)
        if self.use_negatives and c.shape[1] > p:
            m = m - top_mean(c[:, p:], self.k)
        if self.temperature is not None:
            z = float(self.temperature) * m.astype(np.float64)
            m = (0.5 * (1.0 + np.tanh(0.5 * z))).astype(np.float32)
        return (m - np.float32(self.offset)).astype(np.float32)


@dataclass(frozen=True)
class CosineExpansion:
    """A fitted classifier whose decision is a function of cosines with fixed vectors.

    ``c[:, j] = x . labels[j] / |x|`` (``0`` for a zero row) for each map row ``x``;
    ``decision = reduce(c)``. Returned by :meth:`CosineClassifier.cosine_expansion
    <quash_plugins.core.interfaces.CosineClassifier>`: the engine puts the label columns
    of every such query next to the stacked SVMs' columns, so one GEMM per block of the
    map serves them all, and never normalises the map (it scales the GEMM's result by
    ``1 / |x|``).

    Attributes
    ----------
    labels
        ``(L, D)`` float32 vectors (unit text embeddings, or with their norms kept when
        the rule says so).
    reduce
        ``(rows, L)`` float32 cosines to ``(rows,)`` decision values, in numpy. It must
        give what the classifier's ``decision_function`` gives on those rows.
    margin
        The same reduction as a :class:`CosineMargin`, when it is one: executors that do
        not run Python on their data (the GPU pass) use it. ``None``: they copy the
        cosines to the host and call :attr:`reduce`.
    """

    labels: np.ndarray
    reduce: Callable[[np.ndarray], np.ndarray]
    margin: CosineMargin | None = None

    @property
    def width(self) -> int:
        return int(len(self.labels))


def reference_kernel(
    kind: str, A: np.ndarray, B: np.ndarray, gamma: float, power: int
) -> np.ndarray:
    """The kernels of :data:`KINDS` by their definition: the kernel matrix
    ``(len(A), len(B))`` in float64, as used to train precomputed SVCs.

    Cosine of a zero row is defined as 0 (distance 1).
    """
    A = np.asarray(A, dtype=np.float64)
    B = np.asarray(B, dtype=np.float64)
    na = np.linalg.norm(A, axis=1, keepdims=True)
    nb = np.linalg.norm(B, axis=1, keepdims=True)
    Au = np.divide(A, na, out=np.zeros_like(A), where=na > 0)
    Bu = np.divide(B, nb, out=np.zeros_like(B), where=nb > 0)
    cos = Au @ Bu.T
    if kind == "linear-cosine":
        return cos
    d = np.maximum(1.0 - cos, 0.0)
    return np.exp(-gamma * (d**2 if power == 2 else d))
