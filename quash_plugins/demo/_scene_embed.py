"""The voxel embeddings of a proxy scene and the map's record of its encoder.

Every voxel's embedding is the normalised mean of a few appearance names of its object's
class, blended with a neighbouring object's at boundaries, plus semantic confusion,
Gaussian noise, the shared modality offset and the optional non-constant gap
(:func:`_gap`). :func:`voxel_embeddings` draws from the scene's generator in the order
the scene's seed pins, after the layout.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.interfaces import plugin_name

if TYPE_CHECKING:
    from .scene import ClassSet, SceneOptions


def voxel_embeddings(
    encoder: Any,
    cs: ClassSet,
    opts: SceneOptions,
    rng: np.random.Generator,
    inst: np.ndarray,
    cells: np.ndarray,
    labels: np.ndarray,
    cell_inst: np.ndarray,
    inst_class: np.ndarray,
    cache: Any = None,
) -> np.ndarray:
    """The ``(len(cells), D)`` float32 unit embeddings of the occupied ``cells``."""
    from ..core.text import encode_texts

    CLASSES = cs.classes
    # one embedding per distinct appearance name, each encoded once
    names = sorted({n for c in CLASSES for n in c.appearance})
    name_row = {n: i for i, n in enumerate(names)}
    A = encode_texts(encoder, names, cache)
    D = A.shape[1]
    # every object instance mixes a few of its class's appearance names
    V = np.zeros((len(inst_class), D), np.float32)
    for i, ci in enumerate(inst_class):
        app = CLASSES[ci].appearance
        k = min(len(app), opts.names_per_voxel)
        pick = rng.choice(len(app), size=k, replace=False)
        w = rng.dirichlet(np.ones(k) * 2.0)
        v = (w[:, None] * A[[name_row[app[j]] for j in pick]]).sum(axis=0)
        V[i] = v / np.linalg.norm(v)
    E = V[cell_inst].copy()
    partner = _boundary_partner(inst, cells, rng)
    mixed = partner >= 0
    if opts.boundary_blend > 0 and mixed.any():
        wb = rng.uniform(0.0, opts.boundary_blend, int(mixed.sum())).astype(np.float32)
        E[mixed] = (1 - wb[:, None]) * E[mixed] + wb[:, None] * V[partner[mixed]]
    if opts.confusion > 0:  # semantic noise: every voxel also resembles some other object
        other = rng.integers(len(V), size=len(E))
        wc = rng.uniform(0.0, opts.confusion, len(E)).astype(np.float32) ** 2
        E = (1 - wc[:, None]) * E + wc[:, None] * V[other]
    E /= np.linalg.norm(E, axis=1, keepdims=True)
    if opts.noise > 0:
        E += rng.standard_normal(E.shape).astype(np.float32) * (opts.noise / np.sqrt(D))
    offset = rng.standard_normal(D).astype(np.float32)
    E = E / np.linalg.norm(
        E, axis=1, keepdims=True
    ) + opts.modality_offset * offset / np.linalg.norm(offset)
    E = _gap(E, labels, cell_inst, len(CLASSES), len(inst_class), opts)
    E = (E / np.linalg.norm(E, axis=1, keepdims=True)).astype(np.float32)
    return E


_OFFSETS = [
    (dx, dy, dz)
    for dx in (-1, 0, 1)
    for dy in (-1, 0, 1)
    for dz in (-1, 0, 1)
    if (dx, dy, dz) != (0, 0, 0)
]


def _boundary_partner(inst: np.ndarray, cells: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """For each occupied cell, a neighbouring instance of another class (or -1)."""
    own = inst[cells[:, 0], cells[:, 1], cells[:, 2]]
    partner = np.full(len(cells), -1, np.int64)
    shape = np.asarray(inst.shape)
    for k in rng.permutation(len(_OFFSETS)):
        nb = cells + np.asarray(_OFFSETS[k])
        ok = ((nb >= 0) & (nb < shape)).all(axis=1)
        other = np.full(len(cells), -1, np.int64)
        other[ok] = inst[nb[ok, 0], nb[ok, 1], nb[ok, 2]]
        take = (partner < 0) & (other >= 0) & (other != own)
        partner[take] = other[take]
    return partner


def _built_by(encoder: Any) -> dict[str, str]:
    """The map's record of the encoder that built it (``LatentMap.source``), so that a
    query with another encoder is warned about, naming the parameters to write
    (``encoder_params``: :func:`~quash_plugins.adapters._npz.encoder_params` as JSON)."""
    import json

    from ..core.encoder_record import encoder_params

    fingerprint = getattr(encoder, "fingerprint", None)
    if not callable(fingerprint):
        return {}
    # The name a config writes (a factory entry point may build a class of another name).
    record = {"encoder": plugin_name(encoder), "encoder_fingerprint": fingerprint()}
    params = encoder_params(encoder)
    if params is not None:
        record["encoder_params"] = json.dumps(params, allow_nan=False)
    return record


def _unit_rows(rng: np.random.Generator, n: int, d: int) -> np.ndarray:
    v = rng.standard_normal((n, d)).astype(np.float32)
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _gap(E, labels, cell_inst, n_classes, n_inst, opts: SceneOptions) -> np.ndarray:
    """A modality gap that is not one constant vector.

    Applied after the shared offset: a random linear distortion ``E (I + d G / sqrt(D))``
    (``distortion``), one random direction per class of norm ``gap_class`` and one per
    object instance of norm ``gap_instance``. Drawn from its own generator (seeded from
    the scene's seed), so a scene with all three at 0 is byte for byte what it was.
    """
    if not (opts.gap_class or opts.gap_instance or opts.distortion):
        return E
    rng = np.random.default_rng([opts.seed, 12])
    D = E.shape[1]
    if opts.distortion:
        G = rng.standard_normal((D, D)).astype(np.float32) / np.sqrt(D)
        E = E + opts.distortion * (E @ G)
    if opts.gap_class:
        E = E + opts.gap_class * _unit_rows(rng, n_classes, D)[labels]
    if opts.gap_instance:
        E = E + opts.gap_instance * _unit_rows(rng, n_inst, D)[cell_inst]
    return E
