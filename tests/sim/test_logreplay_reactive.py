"""Reactive agents in the closed loop: on their log unless something the simulation changed is in their way."""
from __future__ import annotations

import numpy as np
import pytest
torch = pytest.importorskip("torch")  # a Python without torch skips the file

from pytest_driveeval.io.l5.l5kit_zarr import label_index  # noqa: E402
from pytest_driveeval.metrics.collisions import REAR  # noqa: E402
from pytest_driveeval.policies.baselines import ReplayLogPolicy  # noqa: E402
from pytest_driveeval.sim.agents import TrafficModel  # noqa: E402
from pytest_driveeval.sim.logreplay import EGO_EXTENT, LogArrays, UnrollConfig, scenes_from_arrays, stack_scenes, unroll  # noqa: E402
from pytest_driveeval.sim.logreplay.reactive import ReactiveAgents  # noqa: E402
from pytest_driveeval.synth.scenegen import generate_scenes  # noqa: E402

T, DT, SPEED = 100, 0.1, 10.0
CAR_LENGTH = 4.5
REACTIVE = UnrollConfig(start_frame=10, reactive_agents=ReactiveAgents())
LOG = UnrollConfig(start_frame=10)


def straight_log(agents: list[tuple[float, float]], label: str = "CAR", first_frame: int = 0) -> LogArrays:
    """One scene on a straight road along x: the ego logged at SPEED from x = 0, and
    agents logged at SPEED from (x0, y) each (present from ``first_frame`` on)."""
    n = len(agents)
    shape = (1, T, n)
    time = np.arange(T) * DT
    log = LogArrays(scene_ids=np.array([0]), num_frames=np.array([T]),
                    ego_xy=np.stack([SPEED * time, np.zeros(T)], -1)[None], ego_yaw=np.zeros((1, T)),
                    agent_xy=np.zeros(shape + (2,)), agent_yaw=np.zeros(shape, np.float32),
                    agent_extent=np.zeros(shape + (3,), np.float32),
                    agent_velocity=np.zeros(shape + (2,), np.float32), available=np.zeros(shape, bool),
                    track_id=np.full(shape, -1), label=np.zeros(shape, np.int16), relevant=np.zeros(shape, bool),
                    frame_row=np.full(shape, -1, np.int32))
    for c, (x0, y) in enumerate(agents):
        log.agent_xy[0, :, c] = np.stack([x0 + SPEED * time, np.full(T, y)], -1)
        log.agent_extent[0, :, c] = (CAR_LENGTH, 1.9, 1.5)
        log.agent_velocity[0, :, c, 0] = SPEED
        log.available[0, first_frame:, c] = log.relevant[0, first_frame:, c] = True
        log.track_id[0, first_frame:, c] = c + 1
        log.label[0, first_frame:, c] = label_index(label)
        log.frame_row[0, first_frame:, c] = c
    return log


class Braking(torch.nn.Module):
    """Drives straight on, braking at ``decel`` from frame ``after`` on (the batch's own speed)."""

    def __init__(self, decel: float = 6.0):
        super().__init__()
        self.decel = decel
        self.seen = []

    def forward(self, batch):
        self.seen.append(batch["all_other_agents_history_positions"][:, :, 0].clone())
        v = batch["speed"]
        nxt = torch.clamp(v - self.decel * DT, min=0.0)
        pos = torch.zeros(v.shape[0], 12, 2)
        pos[:, 0, 0] = 0.5 * (v + nxt) * DT
        return {"positions": pos, "yaws": torch.zeros(v.shape[0], 12, 1)}


def bumper_gap(result, column: int) -> np.ndarray:
    """(T,) gap from the ego's rear to the front of the agent behind it in ``column``."""
    ahead = result.driven_xy[0, :, 0] - result.agents.agent_xy[0, :, column, 0]
    return ahead - 0.5 * (EGO_EXTENT[0] + CAR_LENGTH)


def test_log_mode_keeps_the_log_and_pays_for_no_copy():
    log = straight_log([(-15.0, 0.0)])
    result = unroll(log, Braking(), LOG)
    assert result.agents is log and result.reacted is None


def test_nothing_in_the_way_is_log_replay_bit_for_bit():
    # The ego brakes hard, but the agent behind drives in the next lane: nothing is in its way.
    log = straight_log([(-15.0, 3.5)])
    replayed, reactive = unroll(log, Braking(), LOG), unroll(log, Braking(), REACTIVE)
    for name in ("agent_xy", "agent_yaw", "agent_velocity"):
        np.testing.assert_array_equal(getattr(reactive.agents, name), getattr(log, name))
    assert not reactive.reacted.any()
    for name in ("driven_xy", "driven_yaw", "collision_kind", "collision_at_fault", "displacement_error"):
        np.testing.assert_array_equal(getattr(reactive, name), getattr(replayed, name))


@pytest.fixture(scope="module")
def generated():
    return stack_scenes(scenes_from_arrays(generate_scenes(4, 80, seed=3)))


def test_an_ego_on_its_log_changes_nothing(generated):
    """The log replay policy keeps the ego on its log (to float32 precision): nothing reacts."""
    replayed = unroll(generated, ReplayLogPolicy(), UnrollConfig(start_frame=5))
    reactive = unroll(generated, ReplayLogPolicy(), UnrollConfig(start_frame=5, reactive_agents=ReactiveAgents()))
    assert not reactive.reacted.any()
    np.testing.assert_array_equal(reactive.agents.agent_xy, generated.agent_xy)
    np.testing.assert_array_equal(reactive.driven_xy, replayed.driven_xy)


def test_a_follower_brakes_behind_a_braking_ego_instead_of_rear_ending_it():
    log = straight_log([(-15.0, 0.0)])
    replayed = unroll(log, Braking(), LOG)
    hit = np.flatnonzero(replayed.collision_kind[0])
    assert hit.size and replayed.collision_kind[0, hit[0]] == REAR and not replayed.collision_at_fault[0, hit[0]]

    reactive = unroll(log, Braking(), REACTIVE)
    assert not reactive.collision_kind.any()
    gap = bumper_gap(reactive, 0)[10:]
    assert gap.min() >= TrafficModel().min_gap
    assert gap[-1] < TrafficModel().min_gap + 0.5  # it closed up behind the ego, not stopped far back
    assert np.linalg.norm(reactive.agents.agent_velocity[0, -1, 0]) < 0.1
    assert reactive.reacted[0, 11:, 0].any() and not reactive.reacted[0, :11].any()
    assert reactive.agents.available is log.available  # agents exist in the frames the log has them


def test_the_idm_settings_are_used():
    log = straight_log([(-25.0, 0.0)])
    wide = ReactiveAgents(idm=TrafficModel(min_gap=5.0))
    gap = bumper_gap(unroll(log, Braking(), UnrollConfig(start_frame=10, reactive_agents=wide)), 0)[10:]
    # Discrete IDM's last step to a standstill may eat into s0 a little (here 3 cm).
    assert 0.99 * 5.0 <= gap.min() < 5.5


def test_a_follower_reacts_to_another_agent():
    # Ego, then A 15 m behind it, then B 15 m behind A: only A sees the ego, B must brake for A.
    log = straight_log([(-15.0, 0.0), (-30.0, 0.0)])
    reactive = unroll(log, Braking(), REACTIVE)
    a, b = reactive.agents.agent_xy[0, :, 0, 0], reactive.agents.agent_xy[0, :, 1, 0]
    assert reactive.reacted[0, :, 1].any()
    assert (a - b - CAR_LENGTH).min() >= TrafficModel().min_gap
    assert not reactive.collision_kind.any()


def test_pedestrians_replay_the_log():
    log = straight_log([(-15.0, 0.0)], label="PEDESTRIAN")
    reactive = unroll(log, Braking(), REACTIVE)
    assert not reactive.reacted.any()
    np.testing.assert_array_equal(reactive.agents.agent_xy, log.agent_xy)


def test_agents_appearing_later_appear_as_logged():
    log = straight_log([(-35.0, 0.0)], first_frame=40)  # appears ~20 m behind the stopped ego
    reactive = unroll(log, Braking(), REACTIVE)
    np.testing.assert_array_equal(reactive.agents.agent_xy[0, 40, 0], log.agent_xy[0, 40, 0])
    assert reactive.reacted[0, 41:, 0].any() and not reactive.collision_kind.any()


def test_the_policy_sees_the_agents_where_they_are():
    log = straight_log([(-15.0, 0.0)])
    policy = Braking()
    reactive = unroll(log, policy, REACTIVE)
    last = T - 2  # the last frame with a forward
    seen = policy.seen[last - 10][0, 0].numpy()  # slot 0 is the only agent; ego frame, yaw 0
    expected = reactive.agents.agent_xy[0, last, 0] - reactive.driven_xy[0, last]
    assert reactive.reacted[0, last, 0]
    np.testing.assert_allclose(seen, expected, atol=1e-4)
    assert abs(seen[0] - (log.agent_xy[0, last, 0, 0] - reactive.driven_xy[0, last, 0])) > 1.0


def test_reactive_unrolls_are_deterministic(generated):
    from pytest_driveeval.policies.baselines import ConstantVelocityPolicy

    config = UnrollConfig(start_frame=5, drift_threshold=4.0, reactive_agents=ReactiveAgents())
    first, second = (unroll(generated, ConstantVelocityPolicy(), config) for _ in range(2))
    assert first.reacted.any()
    for name in ("agent_xy", "agent_yaw", "agent_velocity"):
        np.testing.assert_array_equal(getattr(first.agents, name), getattr(second.agents, name))
    np.testing.assert_array_equal(first.collision_kind, second.collision_kind)


@pytest.mark.parametrize("options", [dict(corridor=0.0), dict(lookahead_frames=0), dict(creep_speed=-1.0),
                                     dict(labels=("LORRY",))])
def test_bad_options_are_refused(options):
    with pytest.raises(ValueError):
        ReactiveAgents(**options)
