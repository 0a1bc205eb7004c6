"""Plots of evaluation results (matplotlib, imported on use)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..core.atomic import atomic_write
from ..core.errors import QuashError

#: The ``Software`` text of every PNG written here: how a previous plot is recognised.
PNG_SOFTWARE = "quash-plugins"


def is_plot_png(path: str | Path) -> bool:
    """True when ``path`` is a PNG written by :func:`plot_precision_recall`.

    Such a plot may be replaced without ``--force``; any other file may not.
    """
    import struct

    try:
        with open(path, "rb") as f:
            if f.read(8) != b"\x89PNG\r\n\x1a\n":
                return False
            for _ in range(64):  # text chunks come before the image data
                head = f.read(8)
                if len(head) < 8:
                    return False
                length, kind = struct.unpack(">I4s", head)
                if kind in (b"IDAT", b"IEND") or length > 2**20:
                    return False
                data = f.read(length)
                f.read(4)  # CRC
                if kind == b"tEXt" and data == b"Software\0" + PNG_SOFTWARE.encode():
                    return True
    except OSError:
        return False
    return False


def plot_precision_recall(
    configs: Sequence[dict[str, Any]], path: str | Path, title: str = "precision vs recall"
) -> Path:
    """Precision against recall per method (mean: large marker; per query: small dots)."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise QuashError('Plots need matplotlib: pip install "quash-plugins[plots]"') from None
    fig, ax = plt.subplots(figsize=(6.4, 5.2), dpi=110)
    cmap = plt.get_cmap("tab10" if len(configs) <= 10 else "tab20")
    for i, c in enumerate(configs):
        color = cmap(i % cmap.N)
        pq = list((c.get("per_query") or {}).values())
        if pq:
            ax.scatter(
                [q["recall"] for q in pq], [q["precision"] for q in pq], s=9, alpha=0.3, color=color
            )
        if c["mean"]["f1"] is None:  # nothing scored (absence queries only): no mean to place
            continue
        ax.scatter(
            [c["mean"]["recall"]],
            [c["mean"]["precision"]],
            s=90,
            color=color,
            edgecolor="black",
            label=f"{c['name']} (F1 {c['mean']['f1']:.2f})",
            zorder=3,
        )
    r = np.linspace(0.01, 1, 200)
    for f in (0.2, 0.4, 0.6, 0.8):
        p = f * r / (2 * r - f)
        ok = (p > 0) & (p <= 1)
        ax.plot(r[ok], p[ok], color="grey", lw=0.6, ls=":")
    ax.set(xlim=(0, 1.02), ylim=(0, 1.02), xlabel="recall", ylabel="precision", title=title)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    path = Path(path)
    with atomic_write(path, suffix=".png") as tmp:
        fig.savefig(tmp, format="png", metadata={"Software": PNG_SOFTWARE})
    plt.close(fig)
    return path
