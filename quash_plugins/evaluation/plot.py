"""Plots of evaluation results (matplotlib, imported on use)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..core.atomic import atomic_write
from ..core.errors import QuashError


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
        pq = list(c["per_query"].values())
        if pq:
            ax.scatter(
                [q["recall"] for q in pq], [q["precision"] for q in pq], s=9, alpha=0.3, color=color
            )
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
    ax.legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    path = Path(path)
    with atomic_write(path, suffix=".png") as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
    return path
