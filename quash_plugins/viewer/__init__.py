"""Inspect queries in the Rerun viewer.

:class:`RerunLogger` logs a :class:`~quash_plugins.types.LatentMap` and its
:class:`~quash_plugins.types.QueryResult` objects to an explicit
``rerun.RecordingStream``; it never touches Rerun's global recording. The entity
layout, the blueprint and display thinning are described in ``docs/rerun.md``.

This package imports ``rerun`` only when a logger is built, so
``import quash_plugins.viewer`` works without the ``[rerun]`` extra.
"""

from __future__ import annotations

from ._cli import CliRerunLogger, viewer_from_cli, web_viewer_url
from ._display import colormap, display_indices, pca_colors, slugify
from ._rerun import INSTANCE_COLOR, MATCH_COLOR, RerunLogger

__all__ = [
    "INSTANCE_COLOR",
    "MATCH_COLOR",
    "CliRerunLogger",
    "RerunLogger",
    "colormap",
    "display_indices",
    "pca_colors",
    "slugify",
    "viewer_from_cli",
    "web_viewer_url",
]
