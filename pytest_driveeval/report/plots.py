"""Static plots saved as artefacts (matplotlib, headless)."""
from __future__ import annotations

from pathlib import Path
from typing import Mapping

from ..atomic import atomic_path


def bar_chart(path: Path, counts: Mapping[str, float], title: str, ylabel: str = "frames") -> Path:
    """A bar per named count, e.g. closed loop's collision frames by kind and drift resets."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(4.8, 3.2), dpi=100)
    names = list(counts)
    values = [counts[n] for n in names]
    bars = ax.bar(range(len(names)), values, color=["#d32f2f" if v else "#90a4ae" for v in values])
    ax.set_xticks(range(len(names)), names)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.bar_label(bars, fmt="%g")
    ax.set_ylim(0, max(1, max(values, default=0)) * 1.2)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
    return path
