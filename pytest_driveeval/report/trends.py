"""Each item's key figures over the output folder's last runs: a small PNG for the html report and allure.

The history (``history.jsonl``, a line per finished session pointing at its ``summary.json``) is read
once per process and path; a line or a summary that cannot be read (a crash, a hand edit, a run
pruned since) is skipped, never an error: a trend is a view, not a check.
"""
from __future__ import annotations

import io
import json
import math
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Any, Iterator

from ..core.outcome import is_number
from ..core.atomic import MAX_SUMMARY_BYTES, loads_bounded, read_json

#: runs a trend shows besides the current one when the output folder keeps all (keep_runs 0)
DEFAULT_RUNS = 20
#: x-axis labels at most, so twenty dates stay readable in a small plot
LABELS = 6


@dataclass(frozen=True)
class RunFigures:
    """One earlier run: its identity and each item's key figures (numbers only)."""
    id: str
    started: str
    figures: dict[str, dict[str, float]]


#: per history file: (what it was when read, its runs); a session reads it once, a second session
#: in the same process (pytest.main, pytester) once more if a session finished in between
_histories: dict[str, tuple[tuple, list[RunFigures]]] = {}
_plots: dict[tuple, bytes | None] = {}


def read_history(history: Path, limit: int = DEFAULT_RUNS) -> list[RunFigures]:
    """The last ``limit`` readable runs of ``history`` (a history.jsonl), oldest first."""
    try:
        stat = history.stat()
        state: tuple = (limit, stat.st_size, stat.st_mtime_ns)
    except OSError:
        state = (limit, None)
    known = _histories.get(str(history))
    if known is None or known[0] != state:
        _histories[str(history)] = known = (state, _read(history, limit))
    return known[1]


def history_entries(history: Path) -> Iterator[tuple[dict[str, Any], Path]]:
    """(run identity, its summary.json) of each line of ``history`` (a history.jsonl), newest first.  A
    torn or hand-edited line is skipped, and so is a summary path that leads out of the history's folder."""
    try:
        lines = history.read_text(encoding="utf-8", errors="replace").splitlines() if history.is_file() else []
    except OSError:
        return
    for raw in reversed(lines):
        try:
            entry = loads_bounded(raw, str(history))
            run, where = entry["run"], PurePosixPath(entry["summary"])
        except (ValueError, KeyError, TypeError):
            continue
        if isinstance(run, dict) and not where.is_absolute() and ".." not in where.parts:
            yield run, history.parent / where


def _read(history: Path, limit: int) -> list[RunFigures]:
    runs: list[RunFigures] = []
    for run, summary in history_entries(history):
        if len(runs) >= limit:
            break
        found = _run_of(run, summary)
        if found is not None:
            runs.append(found)
    return runs[::-1]


def _run_of(run: dict[str, Any], path: Path) -> RunFigures | None:
    try:
        summary = read_json(path, MAX_SUMMARY_BYTES)
    except ValueError:
        return None
    results = summary.get("results") if isinstance(summary, dict) else None
    if not isinstance(results, list):
        return None
    figures = {}
    for record in results:
        if isinstance(record, dict) and isinstance(record.get("nodeid"), str):
            numbers = record_figures(record)
            if numbers:
                figures[record["nodeid"]] = numbers
    return RunFigures(str(run.get("id", "")), str(run.get("started", "")), figures)


def record_figures(record: dict[str, Any]) -> dict[str, float]:
    """A record's key figures (its comparable payload's; an older record's own figures), numbers only."""
    payload = record.get("baseline")
    figures = payload.get("figures") if isinstance(payload, dict) else None
    if not isinstance(figures, dict):
        figures = record.get("figures") if isinstance(record.get("figures"), dict) else {}
    return {k: float(v) for k, v in figures.items() if is_number(v)}


def series(runs: list[RunFigures], nodeid: str, current: dict[str, Any], current_id: str = "") \
        -> tuple[list[str], dict[str, list[tuple[int, float]]]]:
    """(a label per run, the current one last; per key figure its (run index, value) points).  The
    figures are the current run's key figures, each with the earlier runs that have it; a run without
    the item leaves a gap, not a point."""
    past = [run for run in runs if nodeid in run.figures and run.id != current_id]
    names = [k for k, v in current.items() if is_number(v)]
    labels = [run.started[5:16].replace("T", " ") or run.id for run in past] + ["this run"]
    points = {name: [(i, run.figures[nodeid][name]) for i, run in enumerate(past) if name in run.figures[nodeid]]
              + [(len(past), float(current[name]))] for name in names}
    return labels, points


def trend_png(history: Path, nodeid: str, current: dict[str, Any], current_id: str = "",
              limit: int = DEFAULT_RUNS) -> bytes | None:
    """The item's key figures over the last ``limit`` runs and this one, as PNG bytes; None when
    no earlier run has the item (a single point is no trend) or it has no numeric key figure."""
    labels, points = series(read_history(history, limit), nodeid, current, current_id)
    if len(labels) < 2 or not points or all(len(p) < 2 for p in points.values()):
        return None
    key = (str(history), nodeid, current_id, json.dumps(points, sort_keys=True))
    if key not in _plots:
        _plots[key] = _render(nodeid, labels, points)
    return _plots[key]


def _render(nodeid: str, labels: list[str], points: dict[str, list[tuple[int, float]]]) -> bytes:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    # One small panel per figure, sharing the runs: a rate in % and a distance in m on one axis
    # would flatten one of them.
    fig, axes = plt.subplots(len(points), 1, sharex=True, squeeze=False, dpi=80,
                             figsize=(5.0, 0.55 + 0.85 * len(points)))
    last = len(labels) - 1
    for ax, (name, xy) in zip(axes[:, 0], points.items()):
        xs, ys = [x for x, _ in xy], [y for _, y in xy]
        ax.plot(xs, ys, "-o", color="#546e7a", markersize=3, linewidth=1)
        ax.plot([last], [ys[-1]], "o", markersize=7, markerfacecolor="none", markeredgecolor="#d32f2f",
                markeredgewidth=1.5)
        ax.set_ylabel(name, fontsize=7, rotation=0, ha="right", va="center")
        ax.tick_params(labelsize=6)
        ax.grid(alpha=0.3)
        ax.margins(y=0.25)
    step = max(1, math.ceil(len(labels) / LABELS))
    ticks = sorted(set(range(0, last + 1, step)) | {last})
    axes[-1, 0].set_xticks(ticks, [labels[i] for i in ticks], fontsize=6, rotation=20, ha="right")
    axes[-1, 0].set_xlim(-0.5, last + 0.5)
    fig.suptitle(f"{nodeid}: key figures, last {len(labels)} runs", fontsize=7)
    fig.tight_layout()
    out = io.BytesIO()
    fig.savefig(out, format="png")
    plt.close(fig)
    return out.getvalue()
