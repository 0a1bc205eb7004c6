"""CPU arithmetic helpers of the block passes: threads, a BLAS limit, an exact float16 cast."""

from __future__ import annotations

import contextlib
import os
import threading
from collections.abc import Iterator
from typing import Any

import numpy as np


def cpu_threads() -> int:
    """CPU cores this process may use (``QUASH_CLASSIFY_THREADS`` overrides)."""
    env = os.environ.get("QUASH_CLASSIFY_THREADS")
    if env and env.isdigit() and int(env) > 0:
        return int(env)
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


_CONTROLLER: Any = None
_BLAS_LOCK = threading.Lock()
_BLAS_USERS = 0
_BLAS_LIMIT: Any = None


def _blas_limit() -> Any:
    """threadpoolctl's limit of BLAS to one thread (a no-op without threadpoolctl)."""
    global _CONTROLLER
    try:
        from threadpoolctl import ThreadpoolController
    except ImportError:  # pragma: no cover - shipped with scikit-learn
        return contextlib.nullcontext()
    if _CONTROLLER is None:
        _CONTROLLER = ThreadpoolController()
    return _CONTROLLER.limit(limits=1, user_api="blas")


@contextlib.contextmanager
def blas_single_thread() -> Iterator[None]:
    """BLAS limited to one thread while at least one caller is inside, in this process.

    Reference-counted: threadpoolctl's limit is process-wide, so concurrent passes (Dask
    tasks on a threaded worker, several queries at once) must not each save and restore
    it, or the last to leave could restore a limit another one had set, for good.
    """
    global _BLAS_USERS, _BLAS_LIMIT
    with _BLAS_LOCK:
        if _BLAS_USERS == 0:
            _BLAS_LIMIT = _blas_limit()
            _BLAS_LIMIT.__enter__()
        _BLAS_USERS += 1
    try:
        yield
    finally:
        with _BLAS_LOCK:
            _BLAS_USERS -= 1
            if _BLAS_USERS == 0:
                _BLAS_LIMIT.__exit__(None, None, None)
                _BLAS_LIMIT = None


def sq_norms(x: np.ndarray) -> np.ndarray:
    """Squared row norms ``(r,)``; ``np.vecdot`` (numpy >= 2) is about twice einsum's speed."""
    vecdot = getattr(np, "vecdot", None)
    return vecdot(x, x) if vecdot is not None else np.einsum("ij,ij->i", x, x)


#: Rows converted per step of :func:`half_to_float` (its passes then stay in L1/L2).
HALF_STEP_ROWS = 512
_TWO_112 = np.float32(2.0**112)
_CLEAR_28_30 = np.int32(-1879048193)  # 0x8FFFFFFF
#: :func:`half_to_float` turns a float16 NaN or Inf into a finite value of magnitude
#: ``>= 2**16``; finite float16 values are at most 65504, so a row holding a NaN or Inf
#: has ``|x|^2 >= 2**32`` after the cast (a finite row may too: then check exactly).
HALF_SQ_LIMIT = np.float32(2.0**32)


def half_to_float(src: np.ndarray, out: np.ndarray, step: int = HALF_STEP_ROWS) -> np.ndarray:
    """float16 ``src`` ``(r, D)`` (C-contiguous) into float32 ``out``, exact for every
    finite value, subnormals included; about twice as fast as numpy's own cast.

    The bits are moved into place with integer operations and the exponent rebiased by
    one multiplication by ``2**112``. NaN and Inf come out as finite values of magnitude
    ``>= 2**16`` (see :data:`HALF_SQ_LIMIT`).
    """
    h = src.view(np.int16)
    u = out.view(np.int32)
    for a in range(0, len(src), step):
        hh, uu, oo = h[a : a + step], u[a : a + step], out[a : a + step]
        np.left_shift(hh, np.int32(13), out=uu, dtype=np.int32, casting="unsafe")
        np.bitwise_and(uu, _CLEAR_28_30, out=uu)
        np.multiply(oo, _TWO_112, out=oo)
    return out
