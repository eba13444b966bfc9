"""Use case ``closed_loop``: a planning policy drives the ego through logged
L5 scenes (seed 000), judged on collisions, drift and resets per scene."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..closed_loop import KINDS, judge_scene, select_scenes, unroll_scenes
from ..errors import ModelError
from ..io.l5kit_zarr import L5Dataset
from ..outcome import FAILED, PASSED, Finding, Outcome
from ..usecase import RunContext, UseCase, register_usecase
from .closed_loop_config import ClosedLoopConfig

BASELINES = ("constant_velocity", "log_replay")


def baseline(name: str):
    from ..policies.baselines import ConstantVelocityPolicy, ReplayLogPolicy

    return {"constant_velocity": ConstantVelocityPolicy, "log_replay": ReplayLogPolicy}[name]().eval()


@register_usecase
class ClosedLoop(UseCase):
    name = "closed_loop"
    format_versions = ("0.1.0",)
    config_model = ClosedLoopConfig
    fixtures = ("driveeval_dataset", "driveeval_model")

    def load_dataset(self, ctx: RunContext) -> L5Dataset:
        return L5Dataset.open(super().load_dataset(ctx))

    def load_model(self, ctx: RunContext, spec: str | None):
        from ..policies.loading import load_model

        from_option = spec is not None
        spec = spec or ctx.scenario.config.Model
        if not spec:
            raise ModelError(f"{ctx.scenario.path}: no Model given (Evaluation.Model, --driveeval-model, "
                             "or a driveeval_model fixture)")
        ctx.notes["policy"] = Path(spec).name if spec not in BASELINES and ":" not in spec else spec
        if spec in BASELINES:
            return baseline(spec)
        return load_model(spec, base=None if from_option else ctx.scenario.folder)

    def run(self, config: ClosedLoopConfig, ctx: RunContext) -> Outcome:
        dataset: L5Dataset = ctx.fixtures["driveeval_dataset"]
        spec = config.Unroll
        ids, out_of_range = select_scenes(dataset.num_scenes, spec.Scenes, spec.SceneStride)
        findings = [Finding(f"scene {s} is out of range: {dataset.path} has scenes 0..{dataset.num_scenes - 1}",
                            scene=s, keypath=("Evaluation", "Unroll", "Scenes")) for s in out_of_range]
        unroll = unroll_scenes(dataset, ctx.fixtures["driveeval_model"], ids, start_frame=spec.StartFrame,
                               steps=spec.Steps, drift_threshold=spec.DriftThreshold,
                               freeze_on_collision=spec.FreezeOnCollision, kinematic=spec.Kinematic,
                               history_frames=spec.HistoryFrames, future_frames=spec.FutureFrames,
                               max_agents=spec.MaxAgents) if ids else None
        verdicts = [judge_scene(unroll, row, config.Conditions) for row in range(len(ids))]
        for verdict in verdicts:
            findings.extend(verdict.findings)
        passed = sum(v.passed for v in verdicts)
        rate = 100.0 * passed / len(verdicts) if verdicts else 0.0
        figures = {k: sum(v.figures[k] for v in verdicts) for k in (*KINDS, "at_fault", "displacement_error")}
        figures.update(scenes=len(verdicts), scenes_passed=passed, steps=sum(v.figures["steps"] for v in verdicts))
        if verdicts:
            figures["max_displacement"] = max(v.figures["max_displacement"] for v in verdicts)
        ok = bool(verdicts) and not out_of_range and rate >= config.Conditions.ScenePassRate
        if not ok and rate < config.Conditions.ScenePassRate:
            findings.insert(0, Finding(
                f"{passed} of {len(verdicts)} scene(s) passed ({rate:.1f}%), {config.Conditions.ScenePassRate:g}% "
                "required", figure="scene_pass_rate", value=rate, limit=config.Conditions.ScenePassRate,
                keypath=("Evaluation", "Conditions", "ScenePassRate")))
        summary = (f"{passed}/{len(verdicts)} scenes passed; collisions front {figures['front']}, side "
                   f"{figures['side']}, rear {figures['rear']} ({figures['at_fault']} at fault); "
                   f"{figures['displacement_error']} drift reset(s)")
        artefacts = _artefacts(ctx, config, unroll, verdicts, figures) if unroll is not None else {}
        details = {"policy": ctx.notes.get("policy", "driveeval_model fixture"), "scenes": [{"scene": v.scene, "passed": v.passed, **v.figures,
                               "error": unroll.result.errors[row]} for row, v in enumerate(verdicts)]}
        return Outcome(self.name, PASSED if ok else FAILED, summary, figures=figures, findings=findings,
                       artefacts=artefacts, details=details)


def _artefacts(ctx: RunContext, config: ClosedLoopConfig, unroll, verdicts, figures) -> dict[str, Path]:
    from ..closed_loop import collision_events

    out: dict[str, Path] = {}
    events = {v.scene: collision_events(unroll, row) for row, v in enumerate(verdicts)}
    result_path = ctx.artefact("closed_loop.json")
    result_path.write_text(json.dumps({"scenes": [{"scene": v.scene, "passed": v.passed, "figures": v.figures,
                                                   "collisions": events[v.scene],
                                                   "findings": [f.to_json() for f in v.findings]}
                                                  for v in verdicts]}, indent=1))
    out["result"] = result_path
    if config.Artefacts.Charts:
        from ..report.plots import bar_chart

        counts = {k: figures[k] for k in KINDS} | {"displacement error": figures["displacement_error"]}
        out["chart"] = bar_chart(ctx.artefact("collisions.png"), counts, f"{ctx.scenario.name}: errors by kind")
    wanted = config.Artefacts.Animations
    if wanted != "none":
        from ..policies.batch import EGO_EXTENT
        from ..report.birdseye import render_unroll_gif

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

