"""What a policy_benchmark item leaves beside the summary: a GIF of an episode
with its graph drawn, the comparison of policies with their intervals, and the
per-episode results as JSON.

Recording is cheap (the poses of every episode per step) and happens during
the run; the GIF is drawn afterwards for the episode worth looking at: the
first that did not reach its goal, or the first episode when every one did
and the scenario asks for all.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Callable

import numpy as np

from pytest_driveeval.core.atomic import write_text_atomic
from pytest_driveeval.geometry import box_corners
from pytest_driveeval.metrics.episode_outcomes import GOAL
from pytest_driveeval.core.usecase import RunContext
from pytest_driveeval.usecases.policy_benchmark.evaluate import PolicyRun

__all__ = ["EpisodeRecorder", "episode_gif", "write_artefacts"]


class EpisodeRecorder:
    """An ``on_step`` sink: keeps the poses of every episode at every step."""

    def __init__(self) -> None:
        self.xy: list[np.ndarray] = []
        self.yaw: list[np.ndarray] = []
        self.valid: list[np.ndarray] = []
        self.episodes: Any = None

    def __call__(self, episodes: Any) -> None:
        self.episodes = episodes
        self.xy.append(episodes.xy.copy())
        self.yaw.append(episodes.yaw.copy())
        self.valid.append(episodes.valid.copy())

    def episode(self, row: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(T, A, 2), (T, A), (T, A) of one episode, up to the step it ended."""
        end = int(self.episodes.steps[row]) + 1
        return (np.stack(self.xy)[:end, row], np.stack(self.yaw)[:end, row], np.stack(self.valid)[:end, row])


def _chosen(run: PolicyRun, animations: str) -> int | None:
    failing = np.flatnonzero(run.outcome != GOAL)
    if failing.size:
        return int(failing[0]) if animations != "none" else None
    return 0 if animations == "all" else None


def write_artefacts(ctx: RunContext, run: PolicyRun, recorder: EpisodeRecorder | None, intervals: dict,
                    config: Any, replay: Callable[[int], EpisodeRecorder] | None = None,
                    scene: dict | None = None) -> dict[str, Path]:
    """``replay(row)``: that episode run again alone and recorded, for a run whose episodes ran
    elsewhere (chunks on Ray workers) and were not recorded here; an episode depends on its seed
    alone, so the GIF is the one a recorded local run draws.  ``scene``: a CommonRoad scene's
    identity (scene_names.scene_identity), written to episodes.json and into the GIF's name."""
    from pytest_driveeval.usecases.policy_benchmark.scene_names import gif_part

    out: dict[str, Path] = {}
    result = ctx.artefact("episodes.json")
    write_text_atomic(result, json.dumps({"policy": run.policy, "blueprint": run.blueprint,
                                          **({"scene": scene} if scene else {}), "episodes": [
        {"seed": int(s), "stratum": int(g), "outcome": o, "return": float(r), "steps": int(n)}
        for s, g, o, r, n in zip(run.seeds, run.strata, run.outcome_names(), run.returns, run.steps)]}, indent=1))
    out["episodes"] = result
    if config.Artefacts.ComparisonPlot and intervals:
        from pytest_driveeval.report.plots import interval_chart

        out["comparison"] = interval_chart(ctx.artefact("comparison.png"), intervals,
                                           f"{run.blueprint}: {len(run.seeds)} seeded episodes",
                                           highlight=run.policy)
    row = _chosen(run, config.Artefacts.Animations) if recorder is not None or replay is not None else None
    if row is not None:
        seed = int(run.seeds[row])
        shown, shown_row = (recorder, row) if recorder is not None else (replay(row), 0)
        gif = ctx.artefact(f"episode_seed_{seed}{gif_part(scene)}.gif")
        out[f"episode_{seed}_gif"] = episode_gif(gif, shown, shown_row, config.AgentLimit,
                                                 f"{run.policy} seed {seed}: {run.outcome_names()[row]}")
    return out


def episode_gif(path: Path, recorder: EpisodeRecorder, row: int, agent_limit: int, title: str) -> Path:
    """The GIF of one recorded episode, its road and goal drawn."""
    from pytest_driveeval.report.episode_gif import render_episode_gif

    episodes = recorder.episodes
    xy, yaw, valid = recorder.episode(row)
    scene = episodes.blueprint
    lanelets = getattr(scene, "lanelet_outlines", None)
    if lanelets is not None:  # a CommonRoad scene: its lanelets, its goal's first shape, each obstacle's box
        goal = (scene.goal_outlines[0] if scene.goal_outlines
                else box_corners(episodes.goal_centre[row], episodes.goal_heading[row], np.array([2.0, 2.0])))
        return render_episode_gif(path, xy, yaw, valid, episodes.size, list(lanelets), goal,
                                  agent_limit=agent_limit, title=title)
    road = scene.road
    goal = box_corners(episodes.goal_centre[row], episodes.goal_heading[row], episodes.goal_size[row])
    return render_episode_gif(path, xy, yaw, valid, episodes.size, [lane.outline() for lane in road.lanes]
                              + list(road.areas), goal, agent_limit=agent_limit, title=title)
