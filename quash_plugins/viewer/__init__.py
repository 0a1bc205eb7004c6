"""Inspect queries in the Rerun viewer.

:class:`RerunLogger` logs a :class:`~quash_plugins.core.types.LatentMap` and its
:class:`~quash_plugins.core.types.QueryResult` objects to an explicit
``rerun.RecordingStream``; it never touches Rerun's global recording. The entity
layout, the blueprint and display thinning are described in ``docs/rerun.md``.

This package imports ``rerun`` only when a logger is built, so
``import quash_plugins.viewer`` works without the ``[rerun]`` extra.
"""

from __future__ import annotations

from ._display import colormap, display_indices, pca_colors, slugify
from ._log_eval import EVAL_METRICS
from ._log_map import MATCH_COLOR, REJECTED_COLOR
from ._log_result import INSTANCE_COLOR
from ._machine import display_available, rerun_executable
from ._rerun import RerunLogger, import_rerun
from ._rrd_files import is_quash_app_id, is_quash_rrd, is_rrd, rrd_application_ids
from ._sinks import (
    DEFAULT_BIND,
    DEFAULT_GRPC_PORT,
    DEFAULT_WEB_PORT,
    SinkRerunLogger,
    ViewerOptions,
    check_bind,
    check_connect_url,
    check_distinct_ports,
    check_port,
    check_rrd_name,
    open_viewer,
    web_viewer_url,
)

__all__ = [
    "DEFAULT_BIND",
    "DEFAULT_GRPC_PORT",
    "DEFAULT_WEB_PORT",
    "EVAL_METRICS",
    "INSTANCE_COLOR",
    "MATCH_COLOR",
    "REJECTED_COLOR",
    "RerunLogger",
    "SinkRerunLogger",
    "ViewerOptions",
    "check_bind",
    "check_connect_url",
    "check_distinct_ports",
    "check_port",
    "check_rrd_name",
    "import_rerun",
    "is_quash_app_id",
    "is_quash_rrd",
    "is_rrd",
    "rrd_application_ids",
    "open_viewer",
    "display_available",
    "rerun_executable",
    "colormap",
    "display_indices",
    "pca_colors",
    "slugify",
    "web_viewer_url",
]
