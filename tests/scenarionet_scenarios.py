"""The closed-loop scenario file over a folder of ScenarioNet scenes that the ScenarioNet tests write, in
its variants (declared format, scenes, raster inputs, reactive agents, an executor section as ``tail``):
test_scenarionet_datasets.py and the Ray one in test_closed_loop_ray.py."""
from conftest import REPO_ROOT

#: three real nuScenes-mini scenes, all boston-seaport (fixtures/SOURCES.md): scene-0103, -0553, -0757
FIXTURE_SCENES = REPO_ROOT / "fixtures" / "scenarionet" / "nuscenes"

SCENARIO = """\
ScenarioFormatVersion: 3.0.0
ScenarioName: {name}
Evaluation:
  UseCaseName: closed_loop
  UseCaseFormatVersion: 0.1.0
  Datasets:
    - nuscenes_mini:
        Path: {data}
{format}  Model: {model}
  Unroll:
{unroll}    StartFrame: 10
    Steps: {steps}
  Conditions:
    Collisions: {{Front: 0, Side: 0, Rear: 0, AtFaultOnly: true}}
    Displacement: {displacement}
{tail}"""


def scenario_text(name, data, model="planning_model.pt2", declared=False, scenes=None, raster=False, steps=60,
                  agents=None, displacement="{Max: 30.0}", tail=""):
    unroll = (f"    Scenes: {scenes}\n" if scenes else "") + (
        "    Inputs: {Kind: raster, MapType: py_semantic, RasterSize: [112, 112], PixelSize: [0.5, 0.5], "
        "EgoCenter: [0.25, 0.5]}\n" if raster else "") + (f"    Agents: {agents}\n" if agents else "")
    return SCENARIO.format(name=name, data=data, format="        Format: scenarionet\n" if declared else "",
                           model=REPO_ROOT / "fixtures" / "models" / model, unroll=unroll, steps=steps,
                           displacement=displacement, tail=tail)
