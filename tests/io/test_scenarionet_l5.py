"""ScenarioNet scenes as the closed-loop engine's l5kit-layout scenes: made cases, and the real
nuScenes-mini scenes unrolled."""
import numpy as np
import pytest

from pytest_driveeval.io.l5.l5kit_zarr import label_index
from pytest_driveeval.io.scenarionet.scenarionet import ScenarioNetError, read_scenario
from pytest_driveeval.io.scenarionet.scenarionet_l5 import ScenarioNetDataset, l5_scene

from scenarionet_made import scenario, write


def moving(steps=5):
    data = scenario(steps)
    t = np.arange(steps, dtype=float)
    data["tracks"]["ego"]["state"]["position"] = np.stack([2.0 * t, np.zeros(steps), np.zeros(steps)], 1)
    data["tracks"]["ego"]["state"]["heading"] = np.full(steps, 0.5)
    data["tracks"]["car"]["state"]["position"] = np.stack([t, np.full(steps, 5.0), np.ones(steps)], 1)
    data["tracks"]["car"]["state"]["valid"] = np.array([1, 1, 0, 1, 1][:steps], float)
    return data


def test_each_step_is_a_frame_with_the_cars_pose_and_the_valid_tracks_as_agents(tmp_path):
    scene = l5_scene(read_scenario(write(tmp_path, moving())))
    assert scene.num_frames == 5
    assert np.allclose(scene.ego_positions(), [[2.0 * t, 0.0] for t in range(5)])
    assert np.allclose(scene.ego_yaws(), 0.5)
    assert scene.frames["timestamp"].tolist() == [0, 100_000_000, 200_000_000, 300_000_000, 400_000_000]
    per_frame = [len(scene.agents_of_frame(t)) for t in range(5)]
    assert per_frame == [2, 2, 1, 2, 2]  # the car is missing where it is not valid; the cone always there
    car = scene.agents[scene.agents["track_id"] == 2]  # row 1 of the tracks
    assert np.allclose(car["centroid"], [[0, 5], [1, 5], [3, 5], [4, 5]])
    assert np.argmax(car["label_probabilities"][0]) == label_index("CAR")
    cone = scene.agents[scene.agents["track_id"] == 3]
    assert np.argmax(cone["label_probabilities"][0]) == label_index("UNKNOWN")
    assert np.allclose(cone["extent"][0], [4.5, 2.0, 1.5])


def test_the_scene_ends_where_the_car_stops_being_valid_and_a_car_invalid_at_the_start_is_refused(tmp_path):
    data = moving()
    data["tracks"]["ego"]["state"]["valid"] = np.array([1, 1, 1, 0, 1], float)
    assert l5_scene(read_scenario(write(tmp_path, data))).num_frames == 3
    data["tracks"]["ego"]["state"]["valid"] = np.array([0, 1, 1, 1, 1], float)
    with pytest.raises(ScenarioNetError, match=r"sd_test.pkl \(scenario s1\), track ego \(the self-driving car\): "
                                               "not valid at step 0"):
        l5_scene(read_scenario(write(tmp_path, data)))


def test_a_scene_at_another_rate_is_refused_with_the_way_to_resample(tmp_path):
    data = moving()
    data["metadata"]["sample_rate"] = 0.05
    with pytest.raises(ScenarioNetError, match=r"sampled every 0.05 s \(metadata.sample_rate\); the closed loop steps "
                                               r"every 0.1 s and accepts .*ScenarioNet at 10 Hz"):
        l5_scene(read_scenario(write(tmp_path, data)))


def test_the_real_nuscenes_scenes_replay_their_log_exactly(shared_data):
    from pytest_driveeval.closed_loop import unroll_scenes
    from pytest_driveeval.policies.baselines import ReplayLogPolicy

    dataset = ScenarioNetDataset.open(shared_data / "scenarionet" / "nuscenes")
    assert dataset.num_scenes == 6
    lengths = np.diff(dataset.scenes["frame_index_interval"], axis=1).ravel()
    assert lengths.tolist() == [dataset.source(i).steps for i in range(6)]
    unroll = unroll_scenes(dataset, ReplayLogPolicy(), scenes=list(range(6)), start_frame=10, steps=100)
    # within the engine's float32 steps, as the L5 scene's replay (tests/usecases/closed_loop)
    assert np.nanmax(unroll.result.displacement_error) < 0.01
    assert not unroll.result.collision_at_fault.any()


def test_a_scene_whose_reading_fails_unforeseen_is_that_scenes_error_naming_its_file(tmp_path, monkeypatch):
    import pytest_driveeval.io.scenarionet.scenarionet_l5 as scenarionet_l5

    write(tmp_path, moving(), "sd_a.pkl")
    write(tmp_path, moving(), "sd_b.pkl")
    real = scenarionet_l5.read_scenario

    def read(path):
        if path.name == "sd_b.pkl":
            raise TypeError("something no check foresaw")
        return real(path)

    monkeypatch.setattr(scenarionet_l5, "read_scenario", read)
    dataset = ScenarioNetDataset.open(tmp_path)
    assert dataset.problem(0) is None
    assert "sd_b.pkl could not be read as a ScenarioNet scenario (TypeError: something no check foresaw)" \
        in dataset.problem(1)
    assert np.diff(dataset.scenes["frame_index_interval"], axis=1).ravel().tolist() == [5, 0]


def test_a_dataset_path_that_links_to_a_device_is_read_as_scenarionet_and_named(tmp_path):
    from pytest_driveeval.usecases.closed_loop.datasets import open_dataset

    (tmp_path / "sd_zero.pkl").symlink_to("/dev/zero")
    dataset = open_dataset(tmp_path / "sd_zero.pkl")
    assert "sd_zero.pkl (a link to /dev/zero) is a character device, not a regular file" in dataset.problem(0)
