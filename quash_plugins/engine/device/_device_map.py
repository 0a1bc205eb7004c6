"""A map's embeddings on a torch device: uploaded once, or streamed when too large.

:class:`DeviceMap` uploads the embeddings **as stored** (float16 stays float16; other
non-float32 dtypes become float32) through two pinned host buffers, double-buffered on
a copy stream, so host memory stays bounded by two chunks whatever the map's size. The
squared row norms, the observed mask (``|x|^2 > 0``) and the NaN/Inf check are computed
on the device in the same pass; the map is never normalised in place (normalisation is
a per-row scale the kernels apply to their products). The only host synchronisation is
one at the end of the upload.

A map that does not fit the device budget is not uploaded: :func:`stream_chunks`
yields device chunks of it, read through the same pinned double buffer, for every pass.
"""

from __future__ import annotations

import contextlib
import logging
import weakref
from collections.abc import Iterator
from typing import Any

import numpy as np

from ...core.errors import MapFormatError

log = logging.getLogger(__name__)

#: Fraction of the free device memory a resident map may take.
RESIDENT_SHARE = 0.6


class TensorRows:
    """A torch tensor ``(N, D)`` as the ``embeddings`` of a LatentMap: a map that is
    already on the device (built there, or uploaded by the caller). Reading rows on the
    host copies them back; :class:`DeviceMap` uses the tensor itself.
    """

    def __init__(self, tensor: Any) -> None:
        self.tensor = tensor
        self.shape = tuple(int(s) for s in tensor.shape)
        self.dtype = np.dtype(str(tensor.dtype).removeprefix("torch."))
        self.ndim = len(self.shape)

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, key: Any) -> np.ndarray:
        return self.tensor[key].cpu().numpy()


def torch_dtype(np_dtype: Any) -> Any:
    import torch

    return torch.float16 if np.dtype(np_dtype) == np.float16 else torch.float32


def _host_dtype(np_dtype: Any) -> np.dtype:
    return np.dtype(np.float16) if np.dtype(np_dtype) == np.float16 else np.dtype(np.float32)


class _Staging:
    """Two pinned host buffers and a copy stream (pinned memory only on CUDA).

    Chunk ``k`` goes through host buffer and device buffer ``k % 2``. Before its copy,
    the host waits for the copy that last used the host buffer (chunk ``k - 2``), and the
    copy stream waits (on the device) for the kernels that last read the device buffer
    (those of chunk ``k - 2``, marked when chunk ``k - 1`` was put). The kernels of chunk
    ``k - 1`` are not waited for: that copy overlaps them.
    """

    def __init__(self, rows: int, dim: int, np_dtype: np.dtype, device: Any) -> None:
        import torch

        self.device = torch.device(device)
        self.cuda = self.device.type == "cuda"
        tdt = torch_dtype(np_dtype)
        self.host = [torch.empty((rows, dim), dtype=tdt, pin_memory=self.cuda) for _ in range(2)]
        self.host_np = [h.numpy() for h in self.host]
        self.stream = torch.cuda.Stream(self.device) if self.cuda else None
        self.copied: list[Any] = [None, None]  # H2D copy out of host[i] issued
        self.released: list[Any] = [None, None]  # kernels reading device buffer i issued

    def put(self, i: int, block: Any, dst: Any) -> Any:
        """Copy host rows ``block`` into ``dst`` (device buffer ``i``) via ``host[i]``."""
        import torch

        m = len(block)
        if self.copied[i] is not None:
            self.copied[i].synchronize()
        np.copyto(self.host_np[i][:m], block, casting="unsafe")
        if not self.cuda:
            dst.copy_(self.host[i][:m])
            return dst
        compute = torch.cuda.current_stream(self.device)
        mark = torch.cuda.Event()
        mark.record(compute)  # everything issued so far, incl. the kernels on buffer 1 - i
        self.released[1 - i] = mark
        if self.released[i] is not None:
            self.stream.wait_event(self.released[i])
        with torch.cuda.stream(self.stream):
            dst.copy_(self.host[i][:m], non_blocking=True)
            ev = torch.cuda.Event()
            ev.record(self.stream)
        self.copied[i] = ev
        compute.wait_event(ev)
        return dst


def chunk_rows_for(dim: int, itemsize: int, chunk_bytes: int) -> int:
    return max(1024, int(chunk_bytes) // max(1, dim * itemsize))


class DeviceMap:
    """The embeddings of a :class:`~quash_plugins.core.types.LatentMap` on ``device``.

    Attributes
    ----------
    emb
        ``(N, D)`` tensor as stored (float16 or float32), or None when streamed.
    sq
        ``(N,)`` float32 squared row norms on the device (resident maps).
    observed
        ``(N,)`` bool numpy array (False for zero rows), on the host, computed once.
    """

    def __init__(
        self,
        lmap: Any,
        device: Any = "cuda",
        chunk_bytes: int = 64 * 2**20,
        budget_bytes: int | None = None,
    ) -> None:
        import torch

        self._lmap: Any = lmap
        self.device = torch.device(device)
        if self.device.type == "cuda" and self.device.index is None:
            # "cuda" != "cuda:0" for torch.device: compare tensors' devices by index
            self.device = torch.device("cuda", torch.cuda.current_device())
        self.n, self.dim = lmap.n, lmap.dim
        self.normalize = bool(lmap.normalize)
        self.source = dict(lmap.source)
        self.np_dtype = _host_dtype(lmap.dtype)
        self.chunk_bytes = int(chunk_bytes)
        self.rows = min(self.n, chunk_rows_for(self.dim, self.np_dtype.itemsize, chunk_bytes))
        nbytes = self.n * self.dim * self.np_dtype.itemsize
        if budget_bytes is None:
            budget_bytes = _device_budget(self.device)
        self.resident = nbytes + 4 * self.n <= budget_bytes
        self.emb = None
        self.sq = None
        self.observed: np.ndarray | None = None
        if self.resident:
            self._upload()
            # the device copy is complete: hold the host map weakly, so a cache of
            # device maps keyed by the map object can let both go
            with contextlib.suppress(TypeError):  # no weak references: keep it
                self._lmap = weakref.ref(lmap)

    @property
    def lmap(self) -> Any:
        """The host map (None once a resident map's host object is gone)."""
        return self._lmap() if isinstance(self._lmap, weakref.ref) else self._lmap

    @property
    def dtype(self) -> Any:
        return torch_dtype(self.np_dtype)

    def _upload(self) -> None:
        import torch

        E = self.lmap.embeddings
        if (
            isinstance(E, TensorRows)
            and E.tensor.device == self.device
            and E.tensor.dtype in (torch.float16, torch.float32)
            and E.tensor.stride(1) == 1
        ):
            self._adopt(E.tensor)
            return
        self.emb = torch.empty((self.n, self.dim), dtype=self.dtype, device=self.device)
        self.sq = torch.empty(self.n, dtype=torch.float32, device=self.device)
        staging = _Staging(self.rows, self.dim, self.np_dtype, self.device)
        for k, a in enumerate(range(0, self.n, self.rows)):
            b = min(self.n, a + self.rows)
            dst = staging.put(k % 2, np.asarray(E[a:b]), self.emb[a:b])
            torch.linalg.vector_norm(dst, dim=1, dtype=torch.float32, out=self.sq[a:b])
        self.sq.square_()
        self._finish_checks()

    def _adopt(self, t: Any) -> None:
        """Use a tensor already on the device: only the norms pass runs (chunked)."""
        import torch

        self.emb = t
        self.np_dtype = _host_dtype(np.float16 if t.dtype == torch.float16 else np.float32)
        self.sq = torch.empty(self.n, dtype=torch.float32, device=self.device)
        for a in range(0, self.n, self.rows):
            b = min(self.n, a + self.rows)
            torch.linalg.vector_norm(t[a:b], dim=1, dtype=torch.float32, out=self.sq[a:b])
        self.sq.square_()
        self._finish_checks()

    def _finish_checks(self) -> None:
        """One host synchronisation: the observed mask and the NaN/Inf check."""
        import torch

        finite = torch.isfinite(self.sq)
        obs = self.sq > 0
        both = torch.stack([finite, obs]).cpu().numpy()
        self.observed = both[1]
        if not both[0].all():
            self._raise_or_fix(np.flatnonzero(~both[0]))

    def _raise_or_fix(self, rows: np.ndarray) -> None:
        """Rows whose float32 |x|^2 is not finite: NaN/Inf (an error) or overflow."""
        E = self.lmap.embeddings
        for r in rows:
            row = np.asarray(E[int(r)])
            if not np.isfinite(row).all():
                path = self.source.get("path")
                where = f" in {path}" if path else ""
                raise MapFormatError(
                    f"Field 'embeddings'{where} contains NaN or Inf (first at row {int(r)}). "
                    "Fix or drop those rows before querying."
                )
        self.observed[rows] = True  # huge but finite rows

    def chunks(self, pieces: int = 1) -> Iterator[tuple[int, int, Any]]:
        """``(start, stop, rows on the device)`` covering the map: ``pieces`` views of the
        resident map (none under 2**20 rows), or streamed chunks (:func:`stream_chunks`)."""
        if self.resident:
            step = max(1 << 20, -(-self.n // max(1, pieces)))
            for a in range(0, self.n, step):
                yield a, min(self.n, a + step), self.emb[a : a + step]
            return
        yield from stream_chunks(self.lmap, self.rows, self.device, self.np_dtype)

    def nbytes(self) -> int:
        return self.n * self.dim * self.np_dtype.itemsize


def stream_chunks(
    lmap: Any, rows: int, device: Any, np_dtype: np.dtype | None = None
) -> Iterator[tuple[int, int, Any]]:
    """Device chunks of ``lmap``'s embeddings, read through two pinned host buffers.

    The copy of chunk ``k + 1`` overlaps the kernels launched on chunk ``k`` (the caller
    launches them between two ``next()`` calls); each device buffer is reused only once
    the kernels that read it have been issued before the new copy on the stream order.
    """
    import torch

    np_dtype = np_dtype or _host_dtype(lmap.dtype)
    n, dim = lmap.n, lmap.dim
    rows = min(n, rows)
    staging = _Staging(rows, dim, np_dtype, device)
    dev = [torch.empty((rows, dim), dtype=torch_dtype(np_dtype), device=device) for _ in range(2)]
    E = lmap.embeddings
    for k, a in enumerate(range(0, n, rows)):
        b = min(n, a + rows)
        x = staging.put(k % 2, np.asarray(E[a:b]), dev[k % 2][: b - a])
        yield a, b, x


def _device_budget(device: Any) -> int:
    import torch

    if device.type != "cuda":
        return 1 << 62
    free, _total = torch.cuda.mem_get_info(device)
    return int(free * RESIDENT_SHARE)
