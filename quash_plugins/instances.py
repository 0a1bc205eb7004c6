"""Connected groups of matched items (what a robot navigates to).

Placeholder interface; the adapters issue fills in voxel, point and pixel grouping.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .types import Instance, LatentMap


def find_instances(
    lmap: LatentMap, mask: np.ndarray, scores: np.ndarray, **options: Any
) -> list[Instance]:
    """Group the matched items of ``lmap`` into instances."""
    return []
