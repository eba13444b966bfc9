"""Our CommonRoad episodes' verdicts against CommonRoad's own on the same ego trajectories: goal reached,
collision, off-road at every step, per scenario, as a table.

Drives the ego with a few baselines (keep speed, brake, steer, full throttle, random actions) from
seeded starts (seed 0: the planning problem's initial state; others moved by the scene's start offsets)
until each episode's outcome, records the ego's box centre, heading and speed at every step (the start
included), judges each state with ``CommonRoadEpisodes.judge`` and asks check_trajectory.py, in the
crime venv, for commonroad-io's ``is_reached``, the drivability checker's collision checker and its
lanelet-polygon enclosure on the same states.

Off-road is where the two may differ on purpose: we rasterise the lanelets at ``resolution`` (0.1 m)
and test the box's corners, so a corner within a cell's diagonal (0.141 m, :data:`EDGE`: 0.15 m) of
the road's edge may land on either side; the raster fills hairline gaps between lanelets whose
shared bounds differ slightly in the file, which the drivability checker's polygons (and shapely's
union) keep; and a box whose corners are all on the road while part of it is not (a gap of the road
between its corners) is on the road for us.  Every off-road disagreement is put in one of those
classes by distances and areas (``explain``), or counted as unexplained.

    PYTHONPATH=. python benchmarks/commonroad_oracle/compare_trajectories.py [--data ../shared/data]
"""
from __future__ import annotations

import argparse
import importlib.util
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pytest_driveeval.metrics.episode_outcomes import COLLISION, GOAL, OFF_ROAD, OUTCOME_NAMES
from pytest_driveeval.policies.control_baselines import ConstantAction, RandomAction
from pytest_driveeval.sim.commonroad_scene import commonroad_scene, read_cached
from pytest_driveeval.sim.episodes import reset

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]
SCENARIOS = ["FRA_Anglet-1_1_T-1", "USA_Lanker-1_1_T-1", "USA_US101-3_3_T-1", "ZAM_Tutorial-1_2_T-1"]
FIXTURE = REPO / "fixtures" / "commonroad" / "ZAM_Tutorial-1_2_T-1.xml"
SEEDS = np.arange(4)  # 0: the recorded initial state; 1..3: seeded start offsets
EDGE = 0.15  # m: a 0.1 m cell's diagonal (0.141) and a little
HAIRLINE = 0.01  # m²: the most of the box a gap between two lanelets' shared bounds leaves off the road
CAUSES = ("hairline", "edge", "between corners", "unexplained")
POLICIES = {
    "keep speed": ConstantAction(),
    "brake": ConstantAction(-4.0, 0.0),
    "full throttle": ConstantAction(10.0, 0.0),  # clipped to the ego's bound: runs into what is ahead
    "steer left": ConstantAction(0.0, 0.15),
    "steer right": ConstantAction(0.0, -0.15),
    "drift left": ConstantAction(0.0, 0.01),  # slow off the road: many steps near its edge
    "drift right": ConstantAction(0.0, -0.01),
    "random": RandomAction(salt=24),
}


def _oracle():
    spec = importlib.util.spec_from_file_location("commonroad_oracle_venv", HERE / "oracle_venv.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


ORACLE = _oracle()


@dataclass
class Episode:
    """One policy's episode from one seed: the ego's states at steps 0..end and our verdicts on them."""

    policy: str
    seed: int
    time_step: np.ndarray
    x: np.ndarray
    y: np.ndarray
    yaw: np.ndarray
    speed: np.ndarray
    goal: np.ndarray
    collision: np.ndarray
    off_road: np.ndarray
    outcome: str  # the episode's own outcome at its last step
    theirs: dict = field(default_factory=dict)

    @property
    def name(self) -> str:
        return f"{self.policy} seed {self.seed}"

    def json(self) -> dict:
        return {"name": self.name, "time_step": self.time_step.tolist(), "x": self.x.tolist(),
                "y": self.y.tolist(), "orientation": self.yaw.tolist(), "velocity": self.speed.tolist()}


def run(path: Path, problem_id: int, policy: str) -> list[Episode]:
    """The episodes of ``policy`` from :data:`SEEDS`, each until its outcome, with our verdicts per step."""
    scene = commonroad_scene(path, problem_id)
    eps = reset(scene, SEEDS, agent_limit=4)
    n = len(SEEDS)
    k = [np.zeros(n, np.int64)]
    xy, yaw, speed = [eps.xy[:, 0].copy()], [eps.yaw[:, 0].copy()], [eps.speed[:, 0].copy()]
    alive = [np.ones(n, bool)]
    while not eps.done.all():
        was = ~eps.done
        eps.step(POLICIES[policy].act_on_episodes(eps))
        k.append(eps.steps.copy())
        xy.append(eps.xy[:, 0].copy())
        yaw.append(eps.yaw[:, 0].copy())
        speed.append(eps.speed[:, 0].copy())
        alive.append(was)
    out = []
    for e, seed in enumerate(SEEDS):
        rows = [i for i in range(len(k)) if alive[i][e]]
        steps = np.array([k[i][e] for i in rows])
        p = np.array([xy[i][e] for i in rows])
        h, v = np.array([yaw[i][e] for i in rows]), np.array([speed[i][e] for i in rows])
        goal, collision, off = eps.judge(p, h, v, steps)
        out.append(Episode(policy, int(seed), scene.t0 + steps, p[:, 0], p[:, 1], h, v, goal, collision, off,
                           OUTCOME_NAMES[int(eps.outcome[e])]))
    return out


def scenario_episodes(path: Path, python: Path | None = None) -> list[Episode]:
    """Every policy's episodes in every planning problem of ``path``, with the oracle's verdicts."""
    scenario = read_cached(path)
    scene = commonroad_scene(path, next(iter(scenario.planning_problems)))
    length, width = scene.params.vehicle_length, scene.params.vehicle_width
    out = []
    for problem_id in scenario.planning_problems:
        episodes = [ep for policy in POLICIES for ep in run(path, problem_id, policy)]
        theirs = ORACLE.check_trajectories(path, problem_id, length, width, [ep.json() for ep in episodes],
                                           python=python)
        for ep, answer in zip(episodes, theirs):
            assert answer["name"] == ep.name
            ep.theirs = {k: np.asarray(v) for k, v in answer.items() if k != "name"}
        out += episodes
    return out


def explain(ep: Episode, oracle: str = "off_road") -> dict[str, np.ndarray]:
    """Off-road disagreements of one episode with the oracle's verdict ``oracle`` by cause (boolean masks over
    its steps), first that applies: ``hairline``, on the road for us while the box's area off the lanelets'
    union is at most :data:`HAIRLINE` (gaps between lanelets whose shared bounds differ slightly in the
    file, which the raster's cells fill); ``edge``, a box corner within :data:`EDGE` of the road's edge
    (our raster); ``between
    corners``, every corner on the road while more of the box is off it (our rule tests corners only);
    ``unexplained``, the rest."""
    t = ep.theirs
    left = ep.off_road != t[oracle]
    hairline = left & ~ep.off_road & (t["outside_area"] <= HAIRLINE)
    edge = left & ~hairline & (t["corner_edge_distance"] <= EDGE)
    between = left & ~edge & ~hairline & ~t["corner_off_road"] & ~ep.off_road
    return {"edge": edge, "hairline": hairline, "between corners": between,
            "unexplained": left & ~edge & ~hairline & ~between}


def table(episodes: dict[str, list[Episode]]) -> list[dict]:
    """Per scenario: steps compared, agreement counts, off-road disagreements by cause, outcomes seen."""
    rows = []
    for name, eps in episodes.items():
        row = {"scenario": name, "episodes": len(eps), "steps": sum(len(e.time_step) for e in eps)}
        for what in ("goal", "collision", "off_road"):
            row[what] = sum(int(np.sum(getattr(e, what) == e.theirs[what])) for e in eps)
        row["collision shapely"] = sum(int(np.sum(e.collision == e.theirs["collision_shapely"])) for e in eps)
        for oracle in ("off_road", "off_road_shapely", "corner_off_road"):
            row[oracle + " agree"] = sum(int(np.sum(e.off_road == e.theirs[oracle])) for e in eps)
            row[oracle + " causes"] = [sum(int(np.sum(explain(e, oracle)[c])) for e in eps) for c in CAUSES]
        row["outcomes"] = {o: sum(e.outcome == o for e in eps) for o in sorted({e.outcome for e in eps})}
        theirs_seen = {"goal": 0, "collision": 0, "off_road": 0}
        for e in eps:
            for what in theirs_seen:
                theirs_seen[what] += int(np.any(e.theirs[what]))
        row["oracle episodes with"] = theirs_seen
        rows.append(row)
    return rows


def markdown(rows: list[dict]) -> str:
    """The table; an off-road cell is "agreeing steps (differing by cause: hairline / edge / between corners /
    unexplained)"."""
    head = ("| scenario | episodes | steps | goal agree | collision agree (dc / shapely) | off-road agree: dc "
            "| shapely box | shapely corners | our outcomes | oracle: episodes with goal / collision / off-road |")
    lines = [head, "|" + "---|" * 10]
    for r in rows:
        outcomes = ", ".join(f"{k} {v}" for k, v in r["outcomes"].items())
        seen = " / ".join(str(v) for v in r["oracle episodes with"].values())
        road = " | ".join(f"{r[o + ' agree']} ({' / '.join(map(str, r[o + ' causes']))})"
                          for o in ("off_road", "off_road_shapely", "corner_off_road"))
        lines.append(f"| {r['scenario']} | {r['episodes']} | {r['steps']} | {r['goal']} | {r['collision']} / "
                     f"{r['collision shapely']} | {road} | {outcomes} | {seen} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    default = Path(os.environ.get("DRIVEEVAL_SHARED_DATA", REPO.parent / "shared" / "data"))
    parser.add_argument("--data", type=Path, default=default, help="the shared data folder (commonroad/*.xml)")
    args = parser.parse_args(argv)
    python = ORACLE.checker_python()
    if python is None:
        print(f"the crime venv is absent: run python benchmarks/nuplan_oracle/crime_ttc.py --make-venv", file=sys.stderr)
        return 2
    files = {"fixture ZAM_Tutorial-1_2_T-1": FIXTURE}
    files.update({n: args.data / "commonroad" / f"{n}.xml" for n in SCENARIOS if (args.data / "commonroad").is_dir()})
    print(markdown(table({name: scenario_episodes(path, python) for name, path in files.items()})))
    return 0


if __name__ == "__main__":
    sys.exit(main())
