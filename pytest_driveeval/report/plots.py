"""Static plots saved as artefacts (matplotlib, headless)."""
from __future__ import annotations

from pathlib import Path
from typing import Mapping

from ..core.atomic import atomic_path


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


def interval_chart(path: Path, intervals: Mapping[str, Mapping[str, Mapping[str, float]]], title: str,
                   highlight: str | None = None) -> Path:
    """Policies side by side, one panel per rate: the point and its confidence interval.

    ``intervals[policy][metric] = {"point", "low", "high"}`` in percent; ``highlight`` the policy under test.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    policies = list(intervals)
    metrics = list(dict.fromkeys(m for by_metric in intervals.values() for m in by_metric))
    fig, axes = plt.subplots(1, len(metrics), figsize=(2.6 * len(metrics) + 1.2, 0.45 * len(policies) + 1.4),
                             dpi=100, sharey=True, squeeze=False)
    for ax, metric in zip(axes[0], metrics):
        for row, policy in enumerate(policies):
            value = intervals[policy].get(metric)
            if value is None:
                continue
            colour = "#d32f2f" if policy == highlight else "#546e7a"
            ax.errorbar(value["point"], row, xerr=[[value["point"] - value["low"]], [value["high"] - value["point"]]],
                        fmt="o", color=colour, capsize=3)
        ax.set_title(metric.replace("_", " ") + " (%)", fontsize=9)
        ax.set_xlim(-5, 105)
        ax.grid(axis="x", alpha=0.3)
    axes[0][0].set_yticks(range(len(policies)), policies)
    axes[0][0].invert_yaxis()
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
    return path
