"""SVM classifiers (the paper's choice), fitted with scikit-learn, evaluated fast.

``fit`` trains a :class:`sklearn.svm.SVC`. ``decision_function`` does not call it:
the support vectors, dual coefficients and intercept are extracted once and evaluated
as chunked float32 GEMMs by :class:`~quash_plugins.core.kernels.KernelStack`
(numpy BLAS on the CPU, torch on a GPU). The result equals scikit-learn's
``decision_function`` to 1e-4 (see ``tests/classifiers/test_classifiers_svm.py``).
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np
from sklearn.svm import SVC

from ..core.config import check_device
from ..core.errors import ConfigError
from ..core.expansions import KernelExpansion, KernelPart, reference_kernel
from ..core.interfaces import Classifier
from ..core.kernels import KernelStack, resolve_backend
from ._params import (
    ClassifierParamError,
    check_choice,
    check_class_weight,
    check_finite_rows,
    check_positive,
    map_rows,
    training_set,
    unit_rows,
)

log = logging.getLogger(__name__)

BACKENDS = ("auto", "numpy", "torch")


def _check_gamma(who: str, gamma: Any) -> Any:
    if isinstance(gamma, str):
        if gamma in ("scale", "auto"):
            return gamma
        raise ClassifierParamError(
            f"{who}: parameter 'gamma' is the string {gamma!r}; use 'scale', 'auto' or a "
            "positive number (a string gamma is never silently ignored)."
        )
    return check_positive(who, "gamma", gamma)


class _FastSvm(Classifier):
    """Shared parameters, validation and fast inference of the SVM classifiers.

    scikit-learn's contract: ``__init__`` only stores the parameters, :meth:`fit`
    validates them (and :func:`~quash_plugins.core.registry.create` does, through
    :meth:`check_params`, when a config builds the classifier).
    """

    _who = "svm"

    def check_params(self) -> None:
        """Raise :class:`ClassifierParamError` naming the first invalid parameter."""
        self._check_common()

    def _check_common(self) -> None:
        who = self._who
        check_positive(who, "C", self.C)
        _check_gamma(who, self.gamma)
        check_class_weight(who, self.class_weight)
        check_choice(who, "backend", self.backend, BACKENDS)
        try:  # the config's devices (its `device` key is passed on to the classifier)
            device = check_device(self.device, f"{who}: parameter 'device'")
        except ConfigError as exc:
            raise ClassifierParamError(str(exc)) from None
        if self.backend == "numpy" and device.startswith("cuda"):
            raise ClassifierParamError(f"{who}: backend 'numpy' cannot run on device {device!r}.")
        check_positive(who, "working_set_mb", self.working_set_mb)
        if self.block_rows is not None:
            if isinstance(self.block_rows, bool) or not isinstance(self.block_rows, int):
                raise ClassifierParamError(f"{who}: 'block_rows' must be a positive integer.")
            check_positive(who, "block_rows", self.block_rows)
        if not isinstance(self.unit_rows, bool):
            raise ClassifierParamError(f"{who}: 'unit_rows' must be true or false.")

    def _make_stack(self, part: KernelPart) -> None:
        backend, device = resolve_backend(self.backend, check_device(self.device))
        self.backend_, self.device_ = backend, device
        self.kernel_part_ = part
        self._stack_args = (int(self.working_set_mb * 2**20), self.block_rows)
        self._build_stack()
        self.working_set_width_ = self.stack_.width

    def _build_stack(self) -> None:
        budget, rows = self._stack_args
        self.stack_ = KernelStack([self.kernel_part_], self.backend_, self.device_, budget, rows)

    #: Fitted attributes that scoring a map never reads: a Dask pass ships the
    #: classifier to its workers without them (see ``BlockScorer``); the classifier's
    #: own pickle keeps them. ``svc_`` is scikit-learn's model (its support vectors in
    #: float64), ``X_fit_`` a training set.
    _unused_when_scoring = ("svc_", "X_fit_")

    def __getstate__(self) -> dict[str, Any]:
        """Pickled without ``stack_`` (the GEMM columns, one more copy of the support
        vectors); it is rebuilt from ``kernel_part_`` on first use."""
        state = dict(super().__getstate__())
        state.pop("stack_", None)
        return state

    def __getattr__(self, name: str) -> Any:
        # only reached for a missing attribute: the stack of an unpickled SVM
        if name == "stack_" and "_stack_args" in self.__dict__:
            self._build_stack()
            return self.__dict__[name]
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    def kernel_expansion(self) -> KernelExpansion | None:
        """The fitted decision function for stacking (the ``StackableClassifier`` protocol)."""
        if not hasattr(self, "kernel_part_"):
            return None
        return KernelExpansion(self.kernel_part_, self.backend_, self.device_, self.unit_rows)

    def decision_function(self, E: Any, sq_norms: np.ndarray | None = None) -> np.ndarray:
        """Decision values ``(N,)`` float32, > 0 for matches.

        Parameters
        ----------
        E
            ``(N, D)`` map embeddings, any float dtype (float16 is up-cast block by block).
        sq_norms
            Optional ``(N,)`` squared row norms, when the caller computed them already.

        Raises
        ------
        sklearn.exceptions.NotFittedError
            Before :meth:`fit`.
        ValueError
            NaN or Inf in ``E`` (checked block by block: one extra read of ``E``; the
            pipeline reads a map once and checks it as it reads), complex values, or a
            dimension other than the training set's.
        TypeError
            Sparse ``E``.
        """
        E = map_rows(self, self._who, E)
        check_finite_rows(self._who, E)
        return self.stack_.evaluate(E, sq=sq_norms, unit=self.unit_rows)[:, 0]


class RbfSvmClassifier(_FastSvm):
    """SVC with an RBF kernel ``exp(-gamma |x - s|^2)``: the paper's default classifier.

    Parameters
    ----------
    C
        Regularisation strength (> 0).
    gamma
        ``"scale"`` (``1 / (D * X.var())``, scikit-learn's default), ``"auto"``
        (``1 / D``) or a positive float. Any other string is rejected.
    class_weight
        ``None``, ``"balanced"`` or ``{0: w_negatives, 1: w_positives}``.
    backend
        ``"auto"`` (torch on a visible CUDA GPU, else numpy), ``"numpy"`` or ``"torch"``.
    device
        ``"auto"``, ``"cpu"``, ``"cuda"`` or ``"cuda:N"`` (torch back end), or ``"mps"``
        (the CPU: there is no Apple-GPU path). For direct ``decision_function`` calls; a
        query's pass runs where the pipeline's ``device`` says.
    working_set_mb
        Budget of one block's float32 rows plus its ``(rows, n_support)`` intermediate.
    block_rows
        Rows per block (``None``: cache-sized on the CPU, the whole budget on a GPU).
    unit_rows
        The map's rows are known to be L2-unit: skip computing ``|x|^2``.
    """

    _who = "svm-rbf"

    def __init__(
        self,
        C: float = 1.0,
        gamma: Any = "scale",
        class_weight: Any = None,
        backend: str = "auto",
        device: str = "auto",
        working_set_mb: float = 256.0,
        block_rows: int | None = None,
        unit_rows: bool = False,
    ) -> None:
        self.C = C
        self.gamma = gamma
        self.class_weight = class_weight
        self.backend = backend
        self.device = device
        self.working_set_mb = working_set_mb
        self.block_rows = block_rows
        self.unit_rows = unit_rows

    def fit(self, X: np.ndarray, y: np.ndarray) -> RbfSvmClassifier:
        """Validate the parameters and ``X, y``, fit the SVC, extract its expansion."""
        self.check_params()
        X, y = training_set(self, self._who, X, y)
        self.svc_ = SVC(
            kernel="rbf",
            C=float(self.C),
            gamma=_check_gamma(self._who, self.gamma),
            class_weight=check_class_weight(self._who, self.class_weight),
        )
        self.svc_.fit(X.astype(np.float64), y)
        self.gamma_ = float(self.svc_._gamma)
        self.support_vectors_ = self.svc_.support_vectors_.astype(np.float32)
        self.dual_coef_ = self.svc_.dual_coef_[0].astype(np.float64)
        self.intercept_ = float(self.svc_.intercept_[0])
        self._make_stack(
            KernelPart("rbf", self.support_vectors_, self.dual_coef_, self.intercept_, self.gamma_)
        )
        return self


class CosineSvmClassifier(_FastSvm):
    """SVC with a kernel over cosine distance (the paper's C-SVM).

    Kernels, with ``c = cos(x, s)`` and ``d = 1 - c`` (a zero row has ``c = 0``):

    - ``"rbf-cosine"``: ``exp(-gamma d^2)`` (``distance: squared``) or ``exp(-gamma d)``
      (``distance: plain``);
    - ``"linear-cosine"``: ``c``. ``gamma`` and ``distance`` do not apply and are rejected
      when set.

    ``gamma``: a positive float, ``"scale"`` (``1 / mean(d^p)`` over the distinct
    training pairs, so the kernel is ``exp(-1)`` at the mean distance) or ``"auto"``
    (``1 / D``, as in scikit-learn). Other parameters as in :class:`RbfSvmClassifier`.
    The SVC is trained on the precomputed float64 kernel matrix.
    """

    _who = "svm-cosine"

    def __init__(
        self,
        kernel: str = "rbf-cosine",
        distance: str = "squared",
        C: float = 1.0,
        gamma: Any = "scale",
        class_weight: Any = None,
        backend: str = "auto",
        device: str = "auto",
        working_set_mb: float = 256.0,
        block_rows: int | None = None,
        unit_rows: bool = False,
    ) -> None:
        self.kernel = kernel
        self.distance = distance
        self.C = C
        self.gamma = gamma
        self.class_weight = class_weight
        self.backend = backend
        self.device = device
        self.working_set_mb = working_set_mb
        self.block_rows = block_rows
        self.unit_rows = unit_rows

    def check_params(self) -> None:
        """Raise :class:`ClassifierParamError` naming the first invalid parameter."""
        self._check_common()
        check_choice(self._who, "kernel", self.kernel, ("rbf-cosine", "linear-cosine"))
        check_choice(self._who, "distance", self.distance, ("squared", "plain"))
        if self.kernel == "linear-cosine":
            for field, default in (("gamma", "scale"), ("distance", "squared")):
                if getattr(self, field) != default:
                    raise ClassifierParamError(
                        f"{self._who}: parameter {field!r} does not apply to kernel "
                        "'linear-cosine'; remove it or use kernel 'rbf-cosine'."
                    )

    @property
    def _power(self) -> int:
        return 2 if self.distance == "squared" else 1

    def _resolve_gamma(self, Xu: np.ndarray) -> float:
        if self.kernel == "linear-cosine":
            return 1.0
        gamma = _check_gamma(self._who, self.gamma)
        if gamma == "auto":
            return 1.0 / Xu.shape[1]
        if gamma == "scale":
            d = np.maximum(1.0 - Xu.astype(np.float64) @ Xu.T.astype(np.float64), 0.0)
            dp = d**self._power
            n = len(Xu)
            mean = (dp.sum() - np.trace(dp)) / max(1, n * (n - 1))
            return float(1.0 / mean) if mean > 1e-12 else 1.0
        return float(gamma)

    def fit(self, X: np.ndarray, y: np.ndarray) -> CosineSvmClassifier:
        """Validate the parameters and ``X, y``, fit the SVC on the precomputed kernel."""
        self.check_params()
        X, y = training_set(self, self._who, X, y)
        Xu = unit_rows(X)
        self.gamma_ = self._resolve_gamma(Xu)
        K = reference_kernel(self.kernel, Xu, Xu, self.gamma_, self._power)
        self.svc_ = SVC(
            kernel="precomputed",
            C=float(self.C),
            class_weight=check_class_weight(self._who, self.class_weight),
        )
        self.svc_.fit(K, y)
        self.X_fit_ = Xu
        self.support_vectors_ = Xu[self.svc_.support_]
        self.dual_coef_ = self.svc_.dual_coef_[0].astype(np.float64)
        self.intercept_ = float(self.svc_.intercept_[0])
        if self.kernel == "linear-cosine":
            w = self.dual_coef_ @ self.support_vectors_.astype(np.float64)
            part = KernelPart(
                "linear-cosine", w[None, :].astype(np.float32), np.ones(1), self.intercept_
            )
        else:
            part = KernelPart(
                "rbf-cosine",
                self.support_vectors_,
                self.dual_coef_,
                self.intercept_,
                self.gamma_,
                self._power,
            )
        self._make_stack(part)
        return self
