"""Built-in heuristics: how a query becomes positives and negatives."""

from __future__ import annotations

from ._basic import NoneHeuristic, StaticHeuristic

__all__ = ["NoneHeuristic", "StaticHeuristic"]
