"""Built-in text encoders.

- ``table``: text embeddings looked up from an NPZ or YAML file.
- ``open-clip``: any OpenCLIP text tower (``[clip]`` extra).
- ``sentence-transformers`` / ``minilm``: sentence-transformers models (``[st]`` extra).

Heavy libraries are imported on first use, never at import time.
"""

from __future__ import annotations

from ._table import TableEncoder

__all__ = ["TableEncoder"]
