"""The classification pass on a GPU: a device-resident map and one fused pass per batch.

Selected by ``device: cuda`` (or ``auto`` on a machine with a CUDA GPU); see
:func:`pass_device`. Needs torch, and Triton for the fused kernel (without Triton, a
chunked torch path runs). Nothing here imports torch or Triton until it is used, and the
same code runs on ``device="cpu"`` (torch) and under ``TRITON_INTERPRET=1`` (Triton),
which is how the tests check it without a GPU.

- :class:`DeviceMap`: the embeddings uploaded once, as stored (float16 stays float16),
  through pinned double buffers, with the squared norms, the observed mask and the
  NaN/Inf check computed on the device; a map larger than the device budget is
  streamed in pinned, double-buffered chunks for every pass. :class:`TensorRows` makes
  a tensor already on the device a map.
- :func:`classify_on_device`: the pass (:func:`~quash_plugins.engine.classify_local`'s
  contract): every stacked SVM in one fused Triton launch per piece, every cosine rule
  from one GEMM, anything else on the host.
- :func:`device_unavailable`: why a device asked for is not on this machine (the CLI
  checks ``--device`` and a config's ``device:`` with it before reading a map).
- :func:`device_map`: the cache of device maps the pipeline uses.
"""

from __future__ import annotations

from ...core.optional import lazy_exports

_EXPORTS = {
    "pass_device": "._select",
    "device_unavailable": "._select",
    "device_map": "._select",
    "release_device_maps": "._select",
    "DeviceMap": "._device_map",
    "TensorRows": "._device_map",
    "stream_chunks": "._device_map",
    "classify_on_device": "._classify",
    "triton_available": "._classify",
    "build_plan": "._params",
    "svm_plan_from_parts": "._params",
    "reference_scores": "._params",
    "DeviceSvmPlan": "._torch_svm",
    "DeviceRulePlan": "._torch_svm",
    "svm_scores_torch": "._torch_svm",
    "rule_scores_torch": "._torch_svm",
    "reduce_margin": "._torch_svm",
    "launch": "._triton_svm",  # imports triton
    "best_config": "._triton_svm",
}

__all__ = sorted(_EXPORTS)


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
