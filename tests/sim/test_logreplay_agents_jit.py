"""The compiled paths (numba) of the closed loop against the numpy ones, bit for bit: the agent inputs,
the unroll, stacking scenes; and the numpy paths in a process without numba."""
from __future__ import annotations

import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
torch = pytest.importorskip("torch")  # a Python without torch skips the file

from pytest_driveeval.policies.baselines import ConstantVelocityPolicy  # noqa: E402
from pytest_driveeval.sim.logreplay import (UnrollConfig, build_batch, scenes_from_arrays, stack_scenes, unroll,  # noqa: E402
                                            window_columns)
from pytest_driveeval.sim.logreplay import jit  # noqa: E402
from pytest_driveeval.synth.scenegen import generate_scenes  # noqa: E402

pytestmark = pytest.mark.skipif(not jit.AVAILABLE, reason="numba is not installed: only the numpy path runs")


@pytest.fixture(autouse=True)
def compiled_paths():
    """The compiled paths even for this file's small inputs, which alone would not pay for starting numba."""
    jit.start()

RESULT_FIELDS = ("valid", "driven_xy", "driven_yaw", "collision_kind", "collision_track_id", "collision_at_fault",
                 "displacement_error", "distance_to_reference", "speed_difference", "reset", "frozen")


def _log():
    return stack_scenes(scenes_from_arrays(generate_scenes(4, 80, seed=7)))


def _stacked() -> dict[str, np.ndarray]:
    """Scenes stacked with the default track gap, none, and a long one (other column choices)."""
    scenes = scenes_from_arrays(generate_scenes(3, 90, seed=11))
    out = {}
    for gap in (10, 0, 25):
        log = stack_scenes(scenes, track_gap=gap)
        out.update({f"stack{gap}.{f}": getattr(log, f) for f in log.__dataclass_fields__})
    for history in (0, 3, 10, 200):  # 200: longer than the scenes
        out[f"window{history}.cols"], out[f"window{history}.ok"] = window_columns(log, history)
    return out


def _batches(log) -> dict[str, np.ndarray]:
    """Inputs at random frames, seen from driven poses off the log: some 2 m away, yaws a
    turn and more off (the modulo branch of the wrap), few slots (a choice to make) and
    more slots than candidates (padding)."""
    rng = np.random.default_rng(3)
    xy = log.ego_xy + rng.normal(0.0, 2.0, log.ego_xy.shape)
    yaw = log.ego_yaw + rng.normal(0.0, 1.0, log.ego_yaw.shape)
    yaw[:, ::5] += 20.0
    rows = rng.integers(0, log.shape[0], 200)
    frames = rng.integers(0, log.num_frames[rows])
    out = {}
    for name, options in (("default", {}), ("few", dict(max_agents=3, radius=12.0, history_frames=4)),
                          ("many", dict(max_agents=120))):
        for key, value in build_batch(log, rows, frames, xy, yaw, **options).items():
            out[f"{name}.{key}"] = value.numpy()
    return out


def _unrolled(log) -> dict[str, np.ndarray]:
    with warnings.catch_warnings():  # TorchScript on purpose: the engine runs it as any policy
        warnings.filterwarnings("ignore", r".*torch\.jit\.script` is deprecated", DeprecationWarning)
        policy = torch.jit.script(ConstantVelocityPolicy().eval())
    result = unroll(log, policy, UnrollConfig(drift_threshold=3.0, freeze_on_collision=True, start_frame=2),
                    start_perturbation=np.tile([0.6, -0.4, 0.35, 1.3], (log.shape[0], 1)))
    return {f"unroll.{f}": getattr(result, f) for f in RESULT_FIELDS}


def _assert_same_bits(got: dict, expected: dict) -> None:
    assert got.keys() == expected.keys()
    for key in expected:
        assert got[key].dtype == expected[key].dtype and got[key].shape == expected[key].shape, key
        # Bytes, not values: a masked -0.0 where numpy has +0.0 is a difference too.
        assert got[key].tobytes() == expected[key].tobytes(), key


def test_compiled_inputs_and_unroll_are_the_numpy_ones_bit_for_bit(monkeypatch):
    log = _log()
    compiled = {**_batches(log), **_unrolled(log)}
    assert compiled["default.all_other_agents_history_availability"].any()
    few_slots_used = compiled["few.all_other_agents_history_availability"].any(2).sum(1)
    assert (few_slots_used == 3).sum() > 50  # rows where 3 of more agents had to be chosen
    assert np.signbit(compiled["many.all_other_agents_history_positions"][compiled[
        "many.all_other_agents_history_availability"] == 0]).any()  # masked zeros of both signs are compared
    monkeypatch.setattr(jit, "AVAILABLE", False)
    _assert_same_bits(compiled, {**_batches(log), **_unrolled(log)})


def test_compiled_stacking_is_the_numpy_one_byte_for_byte(monkeypatch):
    compiled = _stacked()
    assert len({compiled[f"stack{g}.available"].shape[2] for g in (10, 0, 25)}) > 1  # the gap changes the columns
    monkeypatch.setattr(jit, "AVAILABLE", False)
    _assert_same_bits(compiled, _stacked())


def test_a_scene_without_agents_stacks_beside_others():
    import dataclasses
    scenes = scenes_from_arrays(generate_scenes(2, 40, seed=5))
    frames = scenes[0].frames.copy()
    frames["agent_index_interval"] = 0
    empty = dataclasses.replace(scenes[0], frames=frames, agents=scenes[0].agents[:0])
    log = stack_scenes([empty, scenes[1]])
    assert not log.available[0].any() and log.available[1].sum() == len(scenes[1].agents)
    # A scene with no agents keeps one empty (never available) agent column, so that every
    # per-agent array has a column to index (a ScenarioNet scene whose only track is the ego).
    alone = stack_scenes([empty])
    assert alone.shape == (1, 40, 1) and not alone.available.any()


def test_compiled_inputs_on_the_real_scene(shared_data, monkeypatch):
    from pytest_driveeval.io.l5.l5kit_zarr import L5Dataset
    scene = L5Dataset.open(shared_data / "l5kit" / "single_scene.zarr").scene(0)
    log = stack_scenes([scene] * 2)
    compiled = {**_batches(log), **{f"stack.{f}": getattr(log, f) for f in log.__dataclass_fields__}}
    assert compiled["default.all_other_agents_history_availability"].sum() > 1000
    monkeypatch.setattr(jit, "AVAILABLE", False)
    log = stack_scenes([scene] * 2)
    _assert_same_bits(compiled, {**_batches(log), **{f"stack.{f}": getattr(log, f) for f in log.__dataclass_fields__}})



@pytest.mark.parametrize("sparse", [False, True])
@pytest.mark.parametrize("repeat", [False, True])
def test_compiled_track_table_is_the_numpy_one(sparse, repeat):
    from pytest_driveeval.io.l5.l5kit_zarr import track_table as numpy_track_table
    from pytest_driveeval.sim.logreplay import logarrays_jit
    from l5kit_rows import random_rows  # tests/l5kit_rows.py

    for seed in range(6):
        rows = random_rows(seed, sparse, repeat)
        got, expected = logarrays_jit.track_table(*rows), numpy_track_table(*rows)
        for name, a, b in zip(got._fields, got, expected):
            assert np.array_equal(a, b) and np.asarray(a).dtype == np.asarray(b).dtype, (seed, name)
        assert (got.repeated_frame >= 0) == repeat

WITHOUT_NUMBA = """
import sys
sys.modules["numba"] = None  # import numba fails: the numpy path
sys.path.insert(0, sys.argv[2])
import numpy as np
import test_logreplay_agents_jit as t
from pytest_driveeval.sim.logreplay import jit
assert not jit.AVAILABLE and not jit.start()
log = t._log()
np.savez(sys.argv[1], **t._batches(log), **t._unrolled(log), **t._stacked())
"""


def test_without_numba_the_inputs_the_unroll_and_the_stacking_are_the_same(tmp_path):
    out = tmp_path / "plain.npz"
    subprocess.run([sys.executable, "-c", WITHOUT_NUMBA, str(out), str(Path(__file__).parent)], check=True,
                   timeout=600)
    log = _log()
    with np.load(out) as plain:
        _assert_same_bits({k: plain[k] for k in plain.files}, {**_batches(log), **_unrolled(log), **_stacked()})


def test_numba_starts_once_the_savings_forgone_pay_for_it(monkeypatch):
    monkeypatch.setattr(jit, "_started", False)
    monkeypatch.setattr(jit, "_forgone", 0.0)
    assert not jit.wanted(0.01)  # a one-scene unroll: the numpy path
    assert not jit.wanted(jit.START_SECONDS - 0.02)  # still short of the start's cost, summed
    assert jit.wanted(0.01)  # now it has paid for itself ...
    assert jit.wanted(0.0)  # ... and from then on everything is compiled
