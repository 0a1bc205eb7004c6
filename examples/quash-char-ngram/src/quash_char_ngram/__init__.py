"""A third-party encoder plugin for quash-plugins: hashed character n-grams.

Each string is split into character n-grams (with word boundaries marked), each n-gram
is hashed to a fixed random direction, and the sum is L2-normalised. Spellings that
share sub-words ("chair", "armchair") land close together. It needs no model weights,
which makes it a handy offline baseline and a complete example of a plugin.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence

import numpy as np

from quash_plugins import Encoder

__all__ = ["CharNgramEncoder"]


class CharNgramEncoder(Encoder):
    """Hashed character n-gram text encoder.

    Parameters
    ----------
    dim
        Output dimension D.
    n_min, n_max
        Range of n-gram lengths.
    seed
        Seed of the random projection; changing it changes the embedding space.
    """

    name = "char-ngram"

    def __init__(self, dim: int = 256, n_min: int = 3, n_max: int = 5, seed: int = 0) -> None:
        if dim <= 0:
            raise ValueError(f"dim must be positive; got {dim}")
        if not 1 <= n_min <= n_max:
            raise ValueError(f"need 1 <= n_min <= n_max; got {n_min}, {n_max}")
        self._dim = int(dim)
        self.n_min = int(n_min)
        self.n_max = int(n_max)
        self.seed = int(seed)
        self._cache: dict[str, np.ndarray] = {}

    @property
    def dim(self) -> int:
        return self._dim

    def _ngrams(self, text: str) -> list[str]:
        grams = []
        for word in text.lower().split():
            w = f"<{word}>"
            for n in range(self.n_min, self.n_max + 1):
                grams.extend(w[i : i + n] for i in range(max(1, len(w) - n + 1)))
        return grams or ["<>"]

    def _direction(self, gram: str) -> np.ndarray:
        vec = self._cache.get(gram)
        if vec is None:
            digest = hashlib.blake2b(f"{self.seed}|{gram}".encode(), digest_size=8).digest()
            rng = np.random.default_rng(int.from_bytes(digest, "little"))
            vec = rng.standard_normal(self._dim)
            self._cache[gram] = vec
        return vec

    def encode_text(self, texts: Sequence[str]) -> np.ndarray:
        out = np.zeros((len(texts), self._dim))
        for i, text in enumerate(texts):
            for gram in self._ngrams(str(text)):
                out[i] += self._direction(gram)
        if len(out):
            out /= np.linalg.norm(out, axis=1, keepdims=True)
        return out.astype(np.float32)

    def config(self) -> dict:
        return {"dim": self._dim, "n_min": self.n_min, "n_max": self.n_max, "seed": self.seed}
