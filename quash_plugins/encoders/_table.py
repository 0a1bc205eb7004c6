"""``table`` encoder: text embeddings computed elsewhere, looked up by exact string."""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import ConfigError, EncoderError, closest
from ..core.interfaces import Encoder


class TableEncoder(Encoder):
    """Look up text embeddings from a table.

    Serves users whose LSeg or OpenSeg text embeddings were computed elsewhere.

    Parameters
    ----------
    file
        NPZ with ``texts (n,) str`` and ``embeddings (n, D)``, or YAML
        ``{text: [floats]}``.
    table
        The same mapping given in memory (instead of ``file``).

    Examples
    --------
    >>> enc = TableEncoder(table={"chair": [3, 4], "other": [1, 0]})
    >>> [round(float(v), 2) for v in enc.encode_text(["chair"])[0]]
    [0.6, 0.8]
    """

    name = "table"

    def __init__(self, file: str | None = None, table: Mapping[str, Any] | None = None) -> None:
        self.file = file
        self.table = table
        if (file is None) == (table is None):
            raise ConfigError("Encoder 'table' needs exactly one of 'file' or 'table'.")
        self._texts, self._emb = self._load()
        self._index = {t: i for i, t in enumerate(self._texts)}

    def _load(self) -> tuple[list[str], np.ndarray]:
        if self.table is not None:
            texts = [str(t) for t in self.table]
            emb = np.asarray([self.table[t] for t in self.table], dtype=np.float32)
            where = "the in-memory table"
        else:
            path = Path(self.file)
            where = str(path)
            if not path.exists():
                raise ConfigError(f"Text-embedding table not found: {path}")
            if path.suffix == ".npz":
                with np.load(path, allow_pickle=False) as z:
                    for key in ("texts", "embeddings"):
                        if key not in z:
                            raise ConfigError(
                                f"{path}: missing array {key!r}. A table NPZ holds "
                                "'texts' (n,) str and 'embeddings' (n, D)."
                            )
                    texts = [str(t) for t in z["texts"]]
                    emb = np.asarray(z["embeddings"], dtype=np.float32)
            elif path.suffix in (".yaml", ".yml"):
                from ..core.yaml_files import load_yaml

                data, _ = load_yaml(path)
                if not isinstance(data, dict):
                    raise ConfigError(f"{path}: expected a mapping {{text: [floats]}}.")
                texts = [str(t) for t in data]
                try:
                    emb = np.asarray(list(data.values()), dtype=np.float32)
                except ValueError:
                    raise ConfigError(f"{path}: every entry must be a list of D numbers.") from None
            else:
                raise ConfigError(f"{path}: table must be .npz or .yaml, got {path.suffix!r}.")
        if emb.ndim != 2 or len(emb) != len(texts) or len(texts) == 0:
            raise ConfigError(
                f"{where}: embeddings must be (n, D) with one row per text; got {emb.shape} "
                f"for {len(texts)} texts."
            )
        if not np.isfinite(emb).all():
            raise ConfigError(f"{where}: embeddings contain NaN or Inf.")
        norms = np.linalg.norm(emb, axis=1, keepdims=True)
        if (norms == 0).any():
            raise ConfigError(f"{where}: {texts[int(np.argmin(norms))]!r} has a zero embedding.")
        return texts, emb / norms

    @property
    def dim(self) -> int:
        return int(self._emb.shape[1])

    @property
    def texts(self) -> list[str]:
        return list(self._texts)

    def encode_text(self, texts: Sequence[str]) -> np.ndarray:
        missing = [t for t in texts if t not in self._index]
        if missing:
            where = self.file or "the in-memory table"
            guess = closest(missing[0], self._texts)
            hint = f" Closest entry: {guess!r}." if guess else ""
            raise EncoderError(
                f"{missing[0]!r} is not in the text-embedding table {where} "
                f"({len(self._texts)} entries; {len(missing)} missing).{hint} Add its "
                "embedding to the table, or use a heuristic whose strings the table covers."
            )
        return self._emb[[self._index[t] for t in texts]].copy()

    @classmethod
    def conformance_params(cls, tmp_path: Path) -> dict[str, Any]:
        """A small table covering the conformance kit's strings."""
        rng = np.random.default_rng(0)
        texts = ["chair", "a red chair", "kitchen sink", "table"]
        path = Path(tmp_path) / "table.npz"
        np.savez(path, texts=np.asarray(texts), embeddings=rng.normal(size=(4, 16)))
        return {"file": str(path)}

    def config(self) -> dict[str, Any]:
        # the texts too: a table whose rows were relabelled is another function
        h = hashlib.sha256(self._emb.tobytes())
        h.update(json.dumps(self._texts).encode())
        digest = h.hexdigest()[:16]
        return {"file": str(self.file) if self.file else None, "sha": digest}
