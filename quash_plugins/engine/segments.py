"""Pieces of a connected component that holds more than one object.

The presence check (:mod:`quash_plugins.engine.presence`) judges the connected
components of a query's mask; a rug matched together with the floor it lies on, or a
laptop with its desk, is one component whose mean is mostly the other object.
:func:`split_components` cuts such a component where its items' features change:
Ward's agglomerative clustering (scikit-learn), merging only neighbours
(:meth:`MapTopology.pairs <quash_plugins.engine.topology.MapTopology.pairs>`).

Examples
--------
>>> import numpy as np
>>> from quash_plugins import LatentMap
>>> from quash_plugins.engine.topology import MapTopology
>>> cells = np.array([(x, 0, 0) for x in range(40)])
>>> topo = MapTopology(LatentMap(np.ones((40, 2), np.float32), grid_index=cells))
>>> rng = np.random.default_rng(0)
>>> feats = np.r_[np.zeros(20), np.ones(20)][:, None] + 0.1 * rng.standard_normal((40, 16))
>>> pieces, of = split_components([np.arange(40)], topo, lambda m: feats[m], 2.5)
>>> sorted((int(p[0]), len(p)) for p in pieces), of  # two objects of 20 cells in a row
([(0, 20), (20, 20)], [0, 0])
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence

import numpy as np

from .topology import MapTopology


def split_components(
    comps: Sequence[np.ndarray],
    topology: MapTopology,
    features: Callable[[np.ndarray], np.ndarray],
    kappa: float,
    min_size: int = 1,
    max_size: int | None = None,
) -> tuple[list[np.ndarray], list[int]]:
    """The pieces of ``comps`` that hold more than one object, and each one's component.

    Each component (sorted item indices) of ``2 * min_size`` to ``max_size`` items is
    clustered on ``features(members)`` (``(n, F)``) with Ward's linkage, merging only
    neighbours, and cut where two regions are further apart than ``kappa`` times the
    median distance between the features of neighbouring items: Ward's distance of two
    regions of one object, ``sqrt(2 n_a n_b / (n_a + n_b)) |mean_a - mean_b|``, has the
    order of that median whatever their sizes, while two objects' grows with their
    sizes. A component that stays in one piece adds none; pieces of under ``min_size``
    items are dropped. Returns ``(pieces, of)``: the pieces (sorted item indices) and
    the index in ``comps`` of each one's component.
    """
    from scipy.sparse import coo_matrix
    from sklearn.cluster import AgglomerativeClustering

    pieces: list[np.ndarray] = []
    of: list[int] = []
    for ci, members in enumerate(comps):
        if len(members) < 2 * min_size or (max_size is not None and len(members) > max_size):
            continue
        i, j = topology.pairs(members)
        if not len(i):
            continue
        F = np.asarray(features(members), np.float64)
        med = float(np.median(np.linalg.norm(F[i] - F[j], axis=1)))
        if not med > 0:
            continue
        n = len(members)
        A = coo_matrix((np.ones(2 * len(i)), (np.r_[i, j], np.r_[j, i])), shape=(n, n)).tocsr()
        with warnings.catch_warnings():
            # items in one cell, or a radius graph in parts: scikit-learn completes it
            warnings.filterwarnings("ignore", message="the number of connected components")
            lab = AgglomerativeClustering(
                n_clusters=None,
                distance_threshold=float(kappa) * med,
                connectivity=A,
                linkage="ward",
            ).fit_predict(F)
        if lab.max() < 1:
            continue
        for k in range(int(lab.max()) + 1):
            part = members[lab == k]
            if len(part) >= min_size:
                pieces.append(part)
                of.append(ci)
    return pieces, of
