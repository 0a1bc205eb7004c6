"""Once per process: the one rule behind every warning the package gives only once.

A benchmark or a long session builds the same config, reads the same map and calls the
same plugin many times; a warning about any of them says what it has to say the first
time. Each caller names its warnings with a key whose first element is its topic
(``("built-by", map, fingerprint, fingerprint)``), so a test can :func:`forget` one topic.

>>> first_time(("doctest", "a"))
True
>>> first_time(("doctest", "a"))
False
>>> forget("doctest"); first_time(("doctest", "a"))
True
"""

from __future__ import annotations

import threading
from collections.abc import Hashable

_lock = threading.Lock()
_seen: set[tuple[Hashable, ...]] = set()


def first_time(key: tuple[Hashable, ...]) -> bool:
    """True the first time ``key`` is seen in this process, False after (thread-safe)."""
    with _lock:
        if key in _seen:
            return False
        _seen.add(key)
        return True


def forget(topic: Hashable) -> None:
    """Forget every key of ``topic`` (its first element), so its warnings are given again."""
    with _lock:
        _seen.difference_update({k for k in _seen if k and k[0] == topic})


__all__ = ["first_time", "forget"]
