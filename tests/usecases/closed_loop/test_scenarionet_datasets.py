"""ScenarioNet scenario folders as closed-loop datasets in a scenario file: recognised from their
files or declared with Format, the real nuScenes-mini scenes driven by the shipped planning model,
with reactive agents and a robustness search as on L5 scenes (on the Ray executor: test_closed_loop_ray.py,
which shares its cluster).  The repository's three Boston scenes (fixtures/scenarionet/nuscenes) need no
shared data; the six in it are used where they are present."""
import json

import numpy as np
import pytest

from conftest import REPO_ROOT
from pytest_driveeval.core.errors import DataError
from pytest_driveeval.usecases.closed_loop.datasets import format_of, open_dataset
from scenarionet_scenarios import FIXTURE_SCENES, scenario_text  # tests/scenarionet_scenarios.py


def summary(pytester, output="driveeval-results") -> dict:
    """The run's records by scenario name."""
    return {r["scenario"]: r for r in
            json.loads((pytester.path / output / "summary.json").read_text())["results"]}

def test_the_files_tell_the_format(shared_data, tmp_path):
    assert format_of(shared_data / "scenarionet" / "nuscenes") == "scenarionet"
    assert format_of(next((shared_data / "scenarionet" / "nuscenes").glob("*.pkl"))) == "scenarionet"
    assert format_of(REPO_ROOT / "fixtures" / "l5kit" / "generated.zarr") == "l5kit"
    with pytest.raises(DataError, match="Format says l5kit, but the files are scenarionet's"):
        open_dataset(shared_data / "scenarionet" / "nuscenes", "l5kit")
    with pytest.raises(DataError, match="Format 'waymo' is not one of l5kit, scenarionet"):
        open_dataset(shared_data / "scenarionet" / "nuscenes", "waymo")


def test_the_planning_model_drives_the_real_nuscenes_scenes_from_a_scenario(pytester, shared_data):
    data = shared_data / "scenarionet" / "nuscenes"
    pytester.makefile(".scenario.yaml", declared=scenario_text("declared", data, declared=True),
                      found=scenario_text("found", data))
    pytester.runpytest("-p", "no:randomly")
    records = json.loads((pytester.path / "driveeval-results" / "summary.json").read_text())["results"]
    assert [r["scenario"] for r in records] == ["declared", "found"]
    for record in records:
        assert record["figures"]["scenes"] == 6 and record["figures"]["steps"] == 6 * 60
        assert [s["scene"] for s in record["details"]["scenes"]] == list(range(6))
        assert all(np.isfinite(s["max_displacement"]) for s in record["details"]["scenes"])
    # Declared or found from the files, the same reader: the same unroll, figure for figure.
    assert records[0]["figures"] == records[1]["figures"]
    assert records[0]["details"]["scenes"] == records[1]["details"]["scenes"]


def test_a_broken_scenario_in_a_folder_fails_alone_and_the_others_run(pytester, shared_data):
    import shutil

    folder = pytester.path / "scenes"
    folder.mkdir()
    real = sorted((shared_data / "scenarionet" / "nuscenes").glob("*.pkl"))
    for path in real[:2]:
        shutil.copy(path, folder / path.name)
    (folder / "sd_zz_cut.pkl").write_bytes(real[2].read_bytes()[:5000])  # truncated
    pytester.makefile(".scenario.yaml", cut=scenario_text("cut", folder))
    pytester.runpytest("-p", "no:randomly")
    record = json.loads((pytester.path / "driveeval-results" / "summary.json").read_text())["results"][0]
    assert record["verdict"] == "failed"
    assert [s["scene"] for s in record["details"]["scenes"]] == [0, 1]  # the readable two were unrolled
    messages = [f["message"] for f in record["findings"] if f.get("scene") == 2]
    assert len(messages) == 1 and "scene 2 (sd_zz_cut.pkl) cannot be read:" in messages[0]
    assert "sd_zz_cut.pkl is not a readable pickle" in messages[0] and "truncated" in messages[0]


def test_the_raster_model_sees_the_scenarios_own_map_and_scenes_of_two_cities_are_refused(pytester, shared_data):
    def scenario(name, scenes):
        return scenario_text(name, shared_data / "scenarionet" / "nuscenes", "raster_model.pt2", scenes=scenes,
                             raster=True, steps=30)

    pytester.makefile(".scenario.yaml", boston=scenario("boston", "[1, 2]"), mixed=scenario("mixed", "[0, 1]"))
    pytester.runpytest("-p", "no:randomly")
    records = {r["scenario"]: r for r in
               json.loads((pytester.path / "driveeval-results" / "summary.json").read_text())["results"]}
    assert records["boston"]["figures"]["scenes"] == 2 and records["boston"]["figures"]["steps"] == 60
    assert records["mixed"]["status"] == "failed"
    assert "lie on 2 maps (boston-seaport, singapore-onenorth)" in records["mixed"]["message"]


# --------------------------------------------------------------------------- the repository's scenes

def test_the_repositorys_scenes_are_a_closed_loop_dataset_without_the_shared_data(pytester):
    assert format_of(FIXTURE_SCENES) == "scenarionet"
    assert [p.name[-8:] for p in open_dataset(FIXTURE_SCENES).files] == ["0103.pkl", "0553.pkl", "0757.pkl"]
    pytester.makefile(".scenario.yaml", fixtures=scenario_text("fixtures", FIXTURE_SCENES, declared=True))
    pytester.runpytest("-p", "no:randomly").assert_outcomes(passed=1)
    record = summary(pytester)["fixtures"]
    assert record["figures"]["scenes"] == 3 and record["figures"]["steps"] == 3 * 60
    assert [s["scene"] for s in record["details"]["scenes"]] == [0, 1, 2]
    assert all(s["error"] is None and np.isfinite(s["max_displacement"]) for s in record["details"]["scenes"])
    # each scene says which scenario and file it is, beside its index (what Scenes: and baselines use)
    first = record["details"]["scenes"][0]
    assert first["identity"] == {"index": 0, "file": "sd_nuscenes_v1.0-mini_scene-0103.pkl",
                                 "scenario_id": "scene-0103"}
    assert first["name"] == "scenario scene-0103, sd_nuscenes_v1.0-mini_scene-0103.pkl"
    written = json.loads((pytester.path / "driveeval-results" / record["artefacts"]["result"]).read_text())
    assert [s["identity"]["scenario_id"] for s in written["scenes"]] == ["scene-0103", "scene-0553", "scene-0757"]


def test_reactive_agents_on_scenarionet_scenes_brake_for_the_car_the_log_drives_into(pytester):
    """Scene-0103 from frame 10: the planning model drifts off the log and logged vehicles drive
    into it from ahead and the side (not its fault); reactive, they brake by IDM, and none does."""
    def scenario(name, agents):
        return scenario_text(name, FIXTURE_SCENES, scenes="[0]", agents=agents,
                             tail="  Artefacts: {Animations: all}\n")

    pytester.makefile(".scenario.yaml", replayed=scenario("replayed", "log"),
                      reactive=scenario("reactive", "reactive"))
    pytester.runpytest("-p", "no:randomly").assert_outcomes(passed=2)
    records = summary(pytester)
    replayed, reactive = records["replayed"]["figures"], records["reactive"]["figures"]
    assert replayed["front"] + replayed["side"] > 0 and replayed["at_fault"] == 0
    assert reactive["front"] + reactive["side"] + reactive["rear"] == 0
    # The model sees the agents where they are: with some braking, what it drives changes too.
    assert records["reactive"]["details"]["scenes"][0]["mean_displacement"] != \
        records["replayed"]["details"]["scenes"][0]["mean_displacement"]
    assert "scene_0_gif" in records["reactive"]["artefacts"]  # drawn from the scenario's own tracks
    # the GIF's name says which scenario it shows; its key stays the index's
    assert records["reactive"]["artefacts"]["scene_0_gif"].endswith("/scene_0_scene-0103.gif")


SEARCH = """\
  Perturbation:
    Heading: [-0.3, 0.3]
    Examples: 32
    Batch: 16
    Tolerance: 0.05
"""


def test_a_robustness_search_on_a_scenarionet_scene_reports_a_replay_line_that_reproduces_it(pytester):
    """Scene-0553, where the logged car stands still and the planning model stays within 0.7 m of
    it: started turned about 0.17 rad to the right, the model rolls backwards into the car behind
    (an at-fault rear collision); turned 0.3 rad to the left, it drifts off the log."""
    pytester.makefile(".scenario.yaml", search=scenario_text("search", FIXTURE_SCENES, scenes="[1]", steps=40,
                                                             displacement="{Max: 4.0, Duration: 1.0}", tail=SEARCH))
    pytester.runpytest("-p", "no:randomly", "--driveeval-search-profile=ci").assert_outcomes(failed=1)
    search = summary(pytester)["search"]["details"]["search"]
    minimal, edge = search["minimal"]["perturbation"]["heading"], search["edge"]["heading"]
    assert search["where"]["scene"] == 1 and 0.1 < abs(minimal) <= 0.3 and abs(edge) < abs(minimal)
    line = search["replay"]
    assert line.startswith("pytest ") and f"--driveeval-replay scene=1,heading={minimal!r}" in line
    node, value = line.split(" ")[1].strip("'"), line.split("--driveeval-replay ", 1)[1]
    pytester.runpytest(node, "--driveeval-replay", value, "--driveeval-output", "replayed").assert_outcomes(failed=1)
    replayed = summary(pytester, "replayed")["search"]
    assert replayed["details"]["replay"] == value and replayed["details"]["perturbation"]["heading"] == minimal
    assert replayed["verdict"] == "failed" and search["reason"] in [f["message"] for f in replayed["findings"]]
    # The edge reported beside it, replayed, passes: the search located the boundary, not any failure.
    pytester.runpytest(node, "--driveeval-replay", f"scene=1,heading={edge!r}", "--driveeval-output", "edge"
                       ).assert_outcomes(passed=1)


def _made():
    """tests/io/scenarionet_made.py, the reader tests' scenario maker (its folder is not on the path here)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("scenarionet_made", REPO_ROOT / "tests" / "io" / "scenarionet_made.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_each_bad_file_of_a_folder_is_that_scenes_error_and_the_good_scenes_beside_it_run(pytester):
    import pickle
    import shutil
    import struct

    made = _made()
    folder = pytester.path / "scenes"
    folder.mkdir()
    shutil.copy(FIXTURE_SCENES / "sd_nuscenes_v1.0-mini_scene-0757.pkl", folder / "sd_a_real.pkl")

    def scene(name, **change):
        made.write(folder, made.scenario(steps=40, **change), f"sd_{name}.pkl")

    def crafted(name, opcodes, **change):
        made.write_crafted(folder, made.scenario(steps=40, **change), opcodes, f"sd_{name}.pkl")

    crafted("b_deep_id", made.deep_list(100_000), id=made.SPLICE)
    scene("c_map_list", map_features=[])
    scene("d_length_text", length="40")
    scene("e_nan_ts", metadata__ts=np.where(np.arange(40) == 3, np.nan, np.arange(40) * 0.1))
    made.write(folder, made.scenario(steps=0), "sd_f_no_steps.pkl")
    (folder / "sd_g_zero.pkl").symlink_to("/dev/zero")
    get = (pickle.SHORT_BINUNICODE + b"\x0bcollections" + pickle.SHORT_BINUNICODE + b"\x0bOrderedDict"
           + pickle.STACK_GLOBAL + pickle.EMPTY_TUPLE + pickle.REDUCE + pickle.EMPTY_DICT + pickle.SHORT_BINUNICODE
           + b"\x03get" + pickle.SHORT_BINUNICODE + b"\x08builtins" + pickle.SHORT_BINUNICODE + b"\x04dict"
           + pickle.STACK_GLOBAL + pickle.SETITEM + pickle.BUILD)
    crafted("h_ordered", get, metadata=made.SPLICE)
    scene("i_nan_size", tracks__car__state__length=np.full(40, np.nan))
    alone = made.scenario(steps=40)
    del alone["tracks"]["car"], alone["tracks"]["cone"]
    made.write(folder, alone, "sd_j_ego_only.pkl")
    bare = made.scenario(steps=40, dynamic_map_states={})
    del bare["map_features"]
    made.write(folder, bare, "sd_k_no_map.pkl")
    def put(n):  # memo numbers of its own, above the scenario's
        return pickle.LONG_BINPUT + struct.pack("<I", 10 ** 6 + n)

    def get(n):
        return pickle.LONG_BINGET + struct.pack("<I", 10 ** 6 + n)

    number = pickle.BINFLOAT + struct.pack(">d", 0.1) + put(0) + pickle.POP
    for level in range(3):  # 464 ** 3 = 1e8 references to one number, in 7 KB
        number += pickle.EMPTY_LIST + put(level + 1) + pickle.MARK + get(level) * 464 + pickle.APPENDS
        number += pickle.POP if level < 2 else b""
    crafted("l_bomb", number, metadata__ts=made.SPLICE)
    scene("m_long", length=30_000_000)

    pytester.makefile(".scenario.yaml", folder=scenario_text("folder", folder, steps=20))
    pytester.runpytest("-p", "no:randomly")
    record = summary(pytester)["folder"]
    assert record["verdict"] == "failed" and record["figures"]["scenes"] == 3
    ran = {s["scene"]: s for s in record["details"]["scenes"]}
    assert sorted(ran) == [0, 9, 10]  # the real scene, the ego alone, the scene without a map
    assert ran[0]["steps"] == ran[9]["steps"] == ran[10]["steps"] == 20
    assert ran[10]["score_terms"]["drivable_area_compliance"]["reason"] == "the scene has no map"
    assert ran[0]["score_terms"]["drivable_area_compliance"]["value"] is not None
    problems = {f["scene"]: f["message"] for f in record["findings"] if "cannot be read" in f["message"]}
    expected = {
        1: "sd_b_deep_id.pkl is refused: at id[0][0][0][0][0]... (33 levels) it nests more than 32 levels deep",
        2: "sd_c_map_list.pkl (scenario s1): map_features is a list of 0 item(s); ScenarioNet gives a mapping",
        3: "sd_d_length_text.pkl (scenario s1): length is str '40', not a whole number of steps",
        4: "sd_e_nan_ts.pkl (scenario s1): metadata.ts is NaN or infinite at step 3",
        5: "sd_f_no_steps.pkl (scenario s1): length is 0 steps: a scenario has at least one step",
        6: "sd_g_zero.pkl (a link to /dev/zero) is a character device, not a regular file",
        7: "sd_h_ordered.pkl is refused: BUILD (setting attributes) on a OrderedDict",
        8: "sd_i_nan_size.pkl (scenario s1), track car: state.length is nan at valid step 0",
        11: "sd_l_bomb.pkl is refused: at metadata.ts it unpacks to more than 512 MiB",
        12: "sd_m_long.pkl (scenario s1): length is 30000000 steps, more than the 36000 a scenario may have",
    }
    assert sorted(problems) == sorted(expected)
    for scene_id, text in expected.items():
        # the index and the file (no scenario id: the file could not be read to tell it)
        file = text.split(" ", 1)[0]
        assert problems[scene_id].startswith(f"scene {scene_id} ({file}) cannot be read: ") \
            and text in problems[scene_id], (scene_id, problems[scene_id])
