"""The classification pass on a torch device (CUDA; ``cpu`` for tests).

:func:`classify_on_device` scores every fitted classifier of a query batch over a
:class:`~quash_plugins.engine.device.DeviceMap`:

- every kernel expansion (``StackableClassifier``: the SVMs, any back end) in **one**
  fused Triton kernel launch per chunk (:mod:`._triton_svm`; the torch fallback
  :func:`._torch_svm.svm_scores_torch` without Triton or off CUDA);
- every cosine expansion (``CosineClassifier``: the peers' rules) from one GEMM per
  chunk, reduced on the device (:class:`~quash_plugins.core.kernels.CosineMargin`);
- anything else (wrapped scikit-learn estimators, plugins) on the host, through the
  CPU block pass (:func:`quash_plugins.engine.classify.classify_local`).

A resident map is one chunk: one launch. A streamed map is read chunk by chunk through
the pinned double buffer. The launches are asynchronous; the host waits once, for the
``(Q, N)`` scores (copied into pinned memory).
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from ._device_map import DeviceMap
from ._params import build_plan
from ._torch_svm import (
    DeviceRulePlan,
    DeviceSvmPlan,
    rule_scores_torch,
    svm_scores_torch,
)

log = logging.getLogger(__name__)


def triton_available(device: Any) -> bool:
    import torch

    if torch.device(device).type != "cuda":
        return False
    try:
        import triton  # noqa: F401
    except ImportError:
        return False
    return True


def classify_on_device(
    dmap: DeviceMap,
    classifiers: list[Any],
    progress: Any = None,
    use_triton: bool | None = None,
    mode: int | None = None,
) -> tuple[list[np.ndarray], np.ndarray]:
    """Scores ``(N,)`` float32 per classifier and the ``(N,)`` observed mask (host).

    ``mode`` is the Triton GEMM mode (see :mod:`._triton_svm`); None: float32-accurate.
    """
    import torch

    classifiers = list(classifiers)
    plan = build_plan(classifiers)
    dev = dmap.device
    if use_triton is None:
        use_triton = triton_available(dev)
    dsvm = DeviceSvmPlan.build(plan.svm, dev) if plan.svm is not None else None
    drule = DeviceRulePlan.build(plan.rules, dev) if plan.rules is not None else None
    n = dmap.n
    n_svm = dsvm.Q if dsvm is not None else 0
    n_rule = len(plan.rules.indices) if plan.rules is not None else 0
    out = torch.empty((n_svm + n_rule, n), dtype=torch.float32, device=dev)
    sq = None if dmap.resident else torch.empty(n, dtype=torch.float32, device=dev)
    host = torch.empty(out.shape, dtype=torch.float32, pin_memory=(dev.type == "cuda"))
    copier = _ResultCopier(out, host, dev)
    with torch.inference_mode():
        for a, b, x in dmap.chunks(pieces=PIECES):
            if dsvm is not None:
                o = out[:n_svm, a:b]
                if use_triton:
                    from ._triton_svm import launch

                    launch(x, dsvm, dmap.normalize, o, None if sq is None else sq[a:b], mode)
                else:
                    svm_scores_torch(x, dsvm, dmap.normalize, o)
            if drule is not None:
                rule_scores_torch(x, drule, [out[n_svm + j, a:b] for j in range(n_rule)])
            if sq is not None and (dsvm is None or not use_triton):
                torch.linalg.vector_norm(x, dim=1, dtype=torch.float32, out=sq[a:b])
                sq[a:b].square_()
            copier.after(a, b)  # this piece's scores go to the host while the next computes
            if progress is not None:
                progress(b - a)
        observed = _observed(sq, dmap) if sq is not None else dmap.observed
        copier.finish()
    arr = host.numpy()
    scores: list[np.ndarray | None] = [None] * len(classifiers)
    if plan.svm is not None:
        for j, i in enumerate(plan.svm.indices):
            scores[i] = arr[j]
    if plan.rules is not None:
        for j, i in enumerate(plan.rules.indices):
            scores[i] = arr[n_svm + j]
    if plan.others:
        from ..classify import classify_local

        rest, _ = classify_local(dmap.lmap, [classifiers[i] for i in plan.others])
        for i, s in zip(plan.others, rest):
            scores[i] = s
    return scores, observed  # type: ignore[return-value]


#: A resident map is scored in this many launches, so that the copy of each piece's
#: scores to the host overlaps the kernel of the next.
PIECES = 8


class _ResultCopier:
    """Copies ``out[:, a:b]`` (device) into ``host[:, a:b]`` (pinned) on a side stream,
    each piece once its kernels are done; the host waits once, in :meth:`finish`."""

    def __init__(self, out: Any, host: Any, device: Any) -> None:
        import torch

        self.out, self.host = out, host
        self.cuda = device.type == "cuda"
        self.stream = torch.cuda.Stream(device) if self.cuda else None
        self.device = device

    def after(self, a: int, b: int) -> None:
        import torch

        if not self.cuda:
            self.host[:, a:b] = self.out[:, a:b]
            return
        done = torch.cuda.Event()
        done.record(torch.cuda.current_stream(self.device))
        self.stream.wait_event(done)
        with torch.cuda.stream(self.stream):
            for q in range(self.out.shape[0]):  # rows of (Q, N): contiguous pieces
                self.host[q, a:b].copy_(self.out[q, a:b], non_blocking=True)

    def finish(self) -> None:
        if self.cuda:
            self.stream.synchronize()  # ``out`` may be freed after this: nothing pending


def _observed(sq: Any, dmap: DeviceMap) -> np.ndarray:
    """The observed mask of a streamed pass, and its NaN/Inf check (one transfer)."""
    import torch

    both = torch.stack([torch.isfinite(sq), sq > 0]).cpu().numpy()
    observed = both[1].copy()
    if not both[0].all():
        dmap.observed = observed
        dmap._raise_or_fix(np.flatnonzero(~both[0]))
        observed = dmap.observed
    return observed
