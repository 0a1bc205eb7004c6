"""Rerun recordings on disk: whether a file is one, and whether quash wrote it (an
``--rrd`` output that may be replaced without ``--force``)."""

from __future__ import annotations

import logging
from pathlib import Path

log = logging.getLogger(__name__)


def is_rrd(path: str | Path) -> bool:
    """True when ``path`` is a Rerun recording (its magic bytes), whoever wrote it.
    :func:`is_quash_rrd` says whether quash wrote it."""
    try:
        with open(path, "rb") as f:
            return f.read(3) == b"RRF"
    except OSError:
        return False


def is_quash_app_id(app_id: str) -> bool:
    """True for the application ids quash records under: ``quash`` (the loggers'
    default) and ``quash-<command>`` (``quash-query``, ``quash-eval``, ``quash-demo``)."""
    return app_id == "quash" or app_id.startswith("quash-")


def rrd_application_ids(path: str | Path) -> list[str] | None:
    """The application ids of the recordings in an ``.rrd`` file, read back with Rerun's
    own reader; None when it cannot be read (not a recording, damaged, no Rerun SDK)."""
    if not is_rrd(path):
        return None
    try:
        from rerun.chunk import RrdReader

        return [str(r.application_id) for r in RrdReader(path).recordings()]
    except Exception as exc:  # ImportError, or the reader's own errors on a damaged file
        log.debug("cannot read the application id of %s: %s", path, exc)
        return None


def is_quash_rrd(path: str | Path) -> bool:
    """True when ``path`` is a Rerun recording that quash wrote (every recording in it
    has a quash application id): a previous ``--rrd`` output that may be replaced
    without ``--force``. A recording of another application (a robot's own log) is not."""
    ids = rrd_application_ids(path)
    return bool(ids) and all(is_quash_app_id(i) for i in ids)
