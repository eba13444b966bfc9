"""What a ``closed_loop`` item leaves next to the summary: closed_loop.json
(every scene's figures, collisions, findings and the ego as driven), a bar chart of collision
frames by kind and drift resets, and bird's-eye GIFs of the scenes (on the scene's map when
the dataset has one, with the places where a score term failed marked).  Plotting libraries load
only when a chart or an animation is wanted.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from pytest_driveeval.core.atomic import write_text_atomic
from pytest_driveeval.core.usecase import RunContext
from pytest_driveeval.usecases.closed_loop.config import ClosedLoopConfig
from pytest_driveeval.usecases.closed_loop.evaluate import KINDS, SceneVerdict, Unroll, collision_events
from pytest_driveeval.usecases.closed_loop.names import caption, gif_name, scene_label

__all__ = ["animated", "chart_counts", "scene_drawn_map", "scene_gif", "write_artefacts", "write_scene_artefacts"]


def write_artefacts(ctx: RunContext, config: ClosedLoopConfig, unroll: Unroll, verdicts: list[SceneVerdict],
                    figures: dict, dataset: Any = None) -> dict[str, Path]:
    """closed_loop.json, the chart of collisions and resets and the scenes' GIFs, as the
    scenario's ``Artefacts`` asks; returns them by artefact name.  A GIF draws its scene's map
    when ``dataset`` has one (scene_map.drawn_map_of) and marks where a score term failed
    (each verdict's ``markers``: frame number, x, y, kind of report.markers.KINDS)."""
    events = {v.scene: collision_events(unroll, row) for row, v in enumerate(verdicts)}

    def draw(row: int, verdict: SceneVerdict) -> Path | None:
        identity = verdict.identity or {"index": verdict.scene}
        return scene_gif(ctx.artefact(gif_name(verdict.scene, identity)), unroll, row, verdict.scene,
                         drawn_map=scene_drawn_map(dataset, verdict.scene),
                         markers=verdict.markers, title=caption(verdict.scene, identity))

    return write_scene_artefacts(ctx, config, verdicts, events, figures, draw)


def animated(config: ClosedLoopConfig, verdict: SceneVerdict) -> bool:
    wanted = config.Artefacts.Animations
    return wanted == "all" or (wanted == "failing" and not verdict.passed)


def write_scene_artefacts(ctx: RunContext, config: ClosedLoopConfig, verdicts: list[SceneVerdict],
                          events: dict[int, list[dict]], figures: dict,
                          draw: Callable[[int, SceneVerdict], Path | None]) -> dict[str, Path]:
    """The artefacts from what was judged: ``draw(row, verdict)`` writes the GIF of a scene the
    scenario wants animated (None when it has no frame), from an unroll here or from the bytes a
    worker drew."""
    out: dict[str, Path] = {}
    result_path = ctx.artefact("closed_loop.json")
    write_text_atomic(result_path, json.dumps({"scenes": [{"scene": v.scene, "name": scene_label(v.identity),
                                                   "identity": v.identity, "passed": v.passed, "figures": v.figures,
                                                   "collisions": events[v.scene],
                                                   "score_terms": v.score_terms,
                                                   "findings": [f.to_json() for f in v.findings],
                                                   "driven": v.driven}
                                                  for v in verdicts]}, indent=1))
    out["result"] = result_path
    if config.Artefacts.Charts:
        from pytest_driveeval.report.plots import bar_chart

        out["chart"] = bar_chart(ctx.artefact("collisions.png"), chart_counts(figures),
                                 f"{ctx.scenario.name}: collisions and drift resets")
    for row, verdict in enumerate(verdicts):
        if animated(config, verdict):
            path = draw(row, verdict)
            if path is not None:
                out[f"scene_{verdict.scene}_gif"] = path
    return out


def scene_drawn_map(dataset: Any, scene: int) -> Any:
    """Scene ``scene``'s map for its GIF, or None (no dataset, or one without maps: an L5 zarr)."""
    if dataset is None:
        return None
    from pytest_driveeval.usecases.closed_loop.scene_map import drawn_map_of

    return drawn_map_of(dataset, scene)


def scene_gif(path: Path, unroll: Unroll, row: int, scene: int, drawn_map: Any = None,
              markers: Sequence[tuple[int, float, float, str]] | None = None, title: str | None = None
              ) -> Path | None:
    """The bird's-eye GIF of scene ``row`` of an unroll, or None when it has no unrolled frame;
    ``drawn_map`` (report.map_layers.DrawnMap) under the boxes, ``markers`` (frame number, x, y,
    kind) where a score term failed, the frame as the log numbers it; ``title``: the caption before
    the frame number (names.caption), "scene N" when not given."""
    from pytest_driveeval.report.birdseye import render_unroll_gif
    from pytest_driveeval.sim.logreplay import EGO_EXTENT

    r, log = unroll.result, unroll.log
    keep = r.valid[row]
    if not keep.any():
        return None
    return render_unroll_gif(path, r.driven_xy[row][keep], r.driven_yaw[row][keep],
                             np.asarray(EGO_EXTENT[:2], dtype=float), r.logged_xy[row][keep],
                             log.agent_xy[row][keep], log.agent_yaw[row][keep], log.agent_extent[row][keep][..., :2],
                             log.available[row][keep], r.collision_kind[row][keep] > 0, title=title or f"scene {scene}",
                             # the log's frame numbers, as closed_loop.json and the findings name them
                             frame_numbers=np.flatnonzero(keep), drawn_map=drawn_map, markers=markers)


def chart_counts(figures: dict) -> dict[str, int]:
    """The chart's bars: collision frames of each kind, then frames put back on the log."""
    return {k: figures[k] for k in KINDS} | {"drift resets": figures["drift_resets"]}

