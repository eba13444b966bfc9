"""What a ``closed_loop`` item leaves next to the summary: closed_loop.json
(every scene's figures, collisions and findings), a bar chart of collision
frames by kind and drift resets, and bird's-eye GIFs of the scenes.  Plotting
libraries load only when a chart or an animation is wanted.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from pytest_driveeval.atomic import write_text_atomic
from pytest_driveeval.usecase import RunContext
from pytest_driveeval.usecases.closed_loop.config import ClosedLoopConfig
from pytest_driveeval.usecases.closed_loop.evaluate import KINDS, SceneVerdict, Unroll, collision_events

__all__ = ["chart_counts", "write_artefacts"]


def write_artefacts(ctx: RunContext, config: ClosedLoopConfig, unroll: Unroll, verdicts: list[SceneVerdict],
                    figures: dict) -> dict[str, Path]:
    """closed_loop.json, the chart of collisions and resets and the scenes' GIFs, as the
    scenario's ``Artefacts`` asks; returns them by artefact name."""
    out: dict[str, Path] = {}
    events = {v.scene: collision_events(unroll, row) for row, v in enumerate(verdicts)}
    result_path = ctx.artefact("closed_loop.json")
    write_text_atomic(result_path, json.dumps({"scenes": [{"scene": v.scene, "passed": v.passed, "figures": v.figures,
                                                   "collisions": events[v.scene],
                                                   "findings": [f.to_json() for f in v.findings]}
                                                  for v in verdicts]}, indent=1))
    out["result"] = result_path
    if config.Artefacts.Charts:
        from pytest_driveeval.report.plots import bar_chart

        out["chart"] = bar_chart(ctx.artefact("collisions.png"), chart_counts(figures),
                                 f"{ctx.scenario.name}: collisions and drift resets")
    wanted = config.Artefacts.Animations
    if wanted != "none":
        from pytest_driveeval.report.birdseye import render_unroll_gif
        from pytest_driveeval.sim.logreplay import EGO_EXTENT

        r, log = unroll.result, unroll.log
        ego_extent = np.asarray(EGO_EXTENT[:2], dtype=float)
        for row, verdict in enumerate(verdicts):
            if wanted == "failing" and verdict.passed:
                continue
            keep = r.valid[row]
            if not keep.any():
                continue
            out[f"scene_{verdict.scene}_gif"] = render_unroll_gif(
                ctx.artefact(f"scene_{verdict.scene}.gif"), r.driven_xy[row][keep], r.driven_yaw[row][keep],
                ego_extent, r.logged_xy[row][keep],
                log.agent_xy[row][keep], log.agent_yaw[row][keep], log.agent_extent[row][keep][..., :2],
                log.available[row][keep], r.collision_kind[row][keep] > 0, title=f"scene {verdict.scene}")
    return out


def chart_counts(figures: dict) -> dict[str, int]:
    """The chart's bars: collision frames of each kind, then frames put back on the log."""
    return {k: figures[k] for k in KINDS} | {"drift resets": figures["drift_resets"]}

