"""What an obstacle_segmentation run leaves on disk: result.jsonl and PNGs of the first failing frames.

:class:`ObstacleArtefacts` is the evaluation's ``on_frame`` sink.  It writes
each frame's line as the frame is judged (a long bag never holds all lines) and
plots a failing frame while its points are still in memory::

    with ObstacleArtefacts(out / "result.jsonl", cfg.condition_record(), out) as artefacts:
        result = evaluate_obstacle_segmentation(dataset, clouds, cfg, on_frame=artefacts)
"""
from __future__ import annotations

from contextlib import AbstractContextManager
from pathlib import Path

import numpy as np

from ...metrics.pointcloud import xyz_columns
from ...report.pointcloud_plot import render_frame_png
from .jsonl import JsonlWriter, final_record, frame_record
from .result import FrameVerdict, ObstacleResult


class ObstacleArtefacts(AbstractContextManager):
    """``jsonl``: where result.jsonl goes (None: no file); ``plots_dir``: where the PNGs of the
    first ``max_plots`` failing frames go (None: no plots).  Close it (or use ``with``) to
    write the final line; that happens after an error too, so nothing judged is lost."""

    def __init__(self, jsonl: str | Path | None, condition: dict, plots_dir: str | Path | None = None,
                 max_plots: int = 5, title_note: str = ""):
        self.title_note = title_note
        self.jsonl = None if jsonl is None else Path(jsonl)
        self.plots: list[Path] = []
        self.plots_dir = None if plots_dir is None else Path(plots_dir)
        self.max_plots = max_plots
        self._writer = None if jsonl is None else JsonlWriter(jsonl, condition)
        self._result: ObstacleResult | None = None

    def __call__(self, frame: FrameVerdict, points: np.ndarray, result: ObstacleResult) -> None:
        self._result = result
        if self._writer is not None:
            self._writer.record(result.success, result.summary, frame.stamp_ns / 1e9, frame_record(frame, result))
        if self.plots_dir is not None and frame.failed and len(self.plots) < self.max_plots:
            self.plots.append(frame_png(self.plots_dir, frame, points, self.title_note))

    def close(self) -> None:
        """Write the final line (once a frame was judged) and close result.jsonl."""
        writer, self._writer = self._writer, None
        if writer is None:
            return
        if self._result is not None:
            writer.write(final_record(self._result))
        writer.close()

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def files(self) -> dict[str, Path]:
        """The artefacts by name, as an Outcome lists them: ``result`` and one per plot."""
        files = {"result": self.jsonl} if self.jsonl is not None else {}
        files.update({p.stem: p for p in self.plots})
        return files


def frame_png(folder: Path, frame: FrameVerdict, points: np.ndarray, note: str = "") -> Path:
    """The bird's-eye PNG of one frame: its cloud in base_link, boxes coloured by status, the area;
    ``note`` ends the title (e.g. the perturbation the cloud was under)."""
    x, y, _ = xyz_columns(points)
    verdicts = [str(s) if t else "Other" for s, t in zip(frame.status, frame.target)]
    labels = [str(u)[:6] for u in frame.gt.instance_tokens]
    areas = [] if frame.area is None else [frame.area.polygon] + list(frame.area.clips or [])
    area_points = frame.counts.area_points
    title = (f"frame {frame.name} @ {frame.stamp_ns / 1e9:.6f}s  Detection: {frame.detection}  "
             f"NonDetection: {frame.non_detection}") + (f"  [{note}]" if note else "")
    return render_frame_png(folder / f"frame_{frame.name}_{frame.stamp_ns}.png", np.stack([x, y], axis=1),
                            frame.boxes.footprints(), verdicts, labels, areas,
                            None if area_points is None else np.asarray(area_points)[:, :2], title)
