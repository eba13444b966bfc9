"""The l5kit zarr v2 reader/writer, against the real sample and broken copies of it."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pytest_driveeval.io.l5.l5kit_zarr import (
    AGENT_DTYPE,
    ARRAY_NAMES,
    FRAME_DTYPE,
    SCENE_DTYPE,
    TL_FACE_DTYPE,
    L5Dataset,
    L5FormatError,
    label_index,
    track_table,
    write_l5_zarr,
)

from l5kit_rows import random_rows  # tests/l5kit_rows.py

# a fast reader / score / report check: CI runs these at the lowest declared versions (-m smoke)
pytestmark = pytest.mark.smoke


@pytest.fixture(scope="module")
def sample(shared_data: Path) -> Path:
    return shared_data / "l5kit" / "single_scene.zarr"


@pytest.fixture
def sample_copy(sample: Path, tmp_path: Path) -> Path:
    dst = tmp_path / "copy.zarr"
    shutil.copytree(sample, dst)
    for p in [dst, *dst.rglob("*")]:  # the shared copy is read-only
        p.chmod(0o755 if p.is_dir() else 0o644)
    return dst


def test_real_sample_counts(sample):
    ds = L5Dataset.open(sample)
    assert ds.num_scenes == 1
    scene = ds.scene(0)
    assert scene.host == "host-a101"
    assert len(scene.frames) == 248
    assert len(scene.agents) == 20_802
    assert len(scene.traffic_light_faces) == 3_216
    assert np.all(np.diff(scene.frames["timestamp"]) > 0)
    assert label_index("CAR") == 3 and ds.attrs["labels"][3] == "PERCEPTION_LABEL_CAR"


def test_real_sample_ego_yaw_matches_rotation(sample):
    scene = L5Dataset.open(sample).scene(0)
    yaw = scene.ego_yaws()
    c, s = np.cos(yaw), np.sin(yaw)
    rot = scene.frames["ego_rotation"]
    # Nearly flat ground: the 2-D part of the rotation is a rotation by yaw.
    np.testing.assert_allclose(rot[:, 0, 0], c, atol=1e-3)
    np.testing.assert_allclose(rot[:, 1, 0], s, atol=1e-3)
    # The ego drives forwards: heading agrees with the direction of travel.
    step = np.diff(scene.ego_positions(), axis=0)
    moving = np.linalg.norm(step, axis=1) > 0.3
    travel = np.arctan2(step[moving, 1], step[moving, 0])
    err = np.angle(np.exp(1j * (travel - yaw[:-1][moving])))
    assert np.median(np.abs(err)) < 0.1


def test_real_sample_agent_tensor_consistent_with_rows(sample):
    scene = L5Dataset.open(sample).scene(0)
    tensor = scene.agent_tensor()
    T, A = tensor.available.shape
    assert T == 248 and A == np.unique(scene.agents["track_id"]).size
    assert tensor.available.sum() == len(scene.agents)
    for t in (0, 100, 247):
        rows = scene.agents_of_frame(t)
        cols = np.searchsorted(tensor.track_id, rows["track_id"])
        assert np.array_equal(tensor.track_id[cols], rows["track_id"])
        assert np.array_equal(np.sort(cols), np.flatnonzero(tensor.available[t]))
        np.testing.assert_array_equal(tensor.centroid[t, cols], rows["centroid"])
        np.testing.assert_array_equal(tensor.yaw[t, cols], rows["yaw"])
        np.testing.assert_array_equal(tensor.extent[t, cols], rows["extent"])
        np.testing.assert_array_equal(tensor.velocity[t, cols], rows["velocity"])
    assert np.all(tensor.centroid[~tensor.available] == 0)


def test_matches_zarr_on_real_sample(sample):
    zarr = pytest.importorskip("zarr")
    store = zarr.open(str(sample), mode="r")
    ours = L5Dataset.open(sample).read_all()
    for name, arr in zip(ARRAY_NAMES, ours):
        theirs = store[name][:]
        assert arr.dtype == theirs.dtype, name
        assert arr.tobytes() == theirs.tobytes(), name


def test_agents_rebased_per_scene(tmp_path):
    from pytest_driveeval.synth.scenegen import generate_scenes

    arrays = generate_scenes(3, 20, seed=5)
    write_l5_zarr(tmp_path / "s.zarr", *arrays, chunk_sizes={"agents": 7, "frames": 6})
    ds = L5Dataset.open(tmp_path / "s.zarr")
    for k in range(3):
        scene = ds.scene(k)
        f0 = scene.frame_offset
        assert f0 == 20 * k
        for t in (0, 19):
            a0, a1 = arrays.frames["agent_index_interval"][f0 + t]
            assert scene.agents_of_frame(t).tobytes() == arrays.agents[a0:a1].tobytes()
            b0, b1 = arrays.frames["traffic_light_faces_index_interval"][f0 + t]
            assert scene.tl_faces_of_frame(t).tobytes() == arrays.traffic_light_faces[b0:b1].tobytes()
    assert ds.scene(-1).index == 2


# --------------------------------------------------------------------------- errors


def test_missing_array(sample_copy):
    shutil.rmtree(sample_copy / "agents")
    with pytest.raises(L5FormatError, match="agents") as err:
        L5Dataset.open(sample_copy)
    assert str(sample_copy) in str(err.value)


def test_wrong_dtype(sample_copy):
    meta_path = sample_copy / "frames" / ".zarray"
    meta = json.loads(meta_path.read_text())
    meta["dtype"][3] = ["ego_translation", "<f4", [3]]
    meta_path.write_text(json.dumps(meta))
    with pytest.raises(L5FormatError) as err:
        L5Dataset.open(sample_copy)
    msg = str(err.value)
    assert "frames" in msg and str(meta_path) in msg
    assert "ego_translation" in msg and "<f4" in msg and "<f8" in msg


def test_missing_field(sample_copy):
    meta_path = sample_copy / "agents" / ".zarray"
    meta = json.loads(meta_path.read_text())
    del meta["dtype"][4]
    meta_path.write_text(json.dumps(meta))
    with pytest.raises(L5FormatError, match=r"missing fields \['track_id'\]"):
        L5Dataset.open(sample_copy)


def test_corrupt_chunk(sample_copy):
    chunk = sample_copy / "agents" / "1"
    chunk.write_bytes(b"this is not blosc" * 10)
    ds = L5Dataset.open(sample_copy)  # metadata is fine; the damage shows on read
    with pytest.raises(L5FormatError) as err:
        ds.scene(0)
    assert str(chunk) in str(err.value) and "agents" in str(err.value)


def test_scene_index_out_of_range(sample):
    ds = L5Dataset.open(sample)
    with pytest.raises(L5FormatError) as err:
        ds.scene(1)
    msg = str(err.value)
    assert "scene index 1" in msg and "[0, 0]" in msg and str(sample) in msg


def test_interval_outside_array(tmp_path):
    from pytest_driveeval.synth.scenegen import generate_scenes

    scenes, frames, agents, faces = generate_scenes(1, 5, seed=0)
    write_l5_zarr(tmp_path / "s.zarr", scenes, frames, agents, faces)
    meta_path = tmp_path / "s.zarr" / "frames" / ".zarray"
    meta = json.loads(meta_path.read_text())
    meta["shape"] = [3]  # scene claims 5 frames
    meta_path.write_text(json.dumps(meta))
    with pytest.raises(L5FormatError, match=r"frame_index_interval = \[0, 5\).*'frames' of length 3"):
        L5Dataset.open(tmp_path / "s.zarr").scene(0)


def test_a_deleted_chunk_is_named_not_read_as_zeros(sample_copy):
    # zarr may omit a chunk that is all fill value, but no L5 chunk is: a
    # missing one was lost, and reading zeros would blame the data's content
    # ("a track id occurs twice in one frame").
    (sample_copy / "agents" / "0").unlink()
    ds = L5Dataset.open(sample_copy)
    with pytest.raises(L5FormatError) as err:
        ds.scene(0)
    assert str(err.value).startswith(f"{sample_copy}: chunk 0 of array 'agents' (rows 0..")
    assert f"is missing: {sample_copy / 'agents' / '0'} does not exist" in str(err.value)
    assert "track id" not in str(err.value)


def test_a_deleted_edge_chunk_of_a_generated_dataset_is_named(tmp_path):
    scenes = np.zeros(1, SCENE_DTYPE)
    scenes[0] = ((0, 4), "h", 0, 3)
    frames = np.zeros(4, FRAME_DTYPE)
    write_l5_zarr(tmp_path / "s.zarr", scenes, frames, np.zeros(0, AGENT_DTYPE), np.zeros(0, TL_FACE_DTYPE),
                  chunk_sizes={"frames": 3})
    (tmp_path / "s.zarr" / "frames" / "1").unlink()
    with pytest.raises(L5FormatError, match=r"chunk 1 of array 'frames' \(rows 3..3\) is missing"):
        L5Dataset.open(tmp_path / "s.zarr").scene(0)


def test_writer_rejects_bad_input(tmp_path):
    scenes = np.zeros(1, SCENE_DTYPE)
    scenes[0]["frame_index_interval"] = (0, 2)
    with pytest.raises(L5FormatError, match=r"scenes\[0\]\.frame_index_interval"):
        write_l5_zarr(tmp_path / "a", scenes, np.zeros(1, FRAME_DTYPE), np.zeros(0, AGENT_DTYPE),
                      np.zeros(0, TL_FACE_DTYPE))
    with pytest.raises(L5FormatError, match="'agents'.*wrong dtype"):
        write_l5_zarr(tmp_path / "b", np.zeros(0, SCENE_DTYPE), np.zeros(0, FRAME_DTYPE),
                      np.zeros(0, np.float64), np.zeros(0, TL_FACE_DTYPE))


# --------------------------------------------------------------------------- round trip

_int64 = st.integers(-(2**62), 2**62)
_f32 = st.floats(-1e6, 1e6, width=32)


@st.composite
def _l5_arrays(draw):
    """Random small but consistent stores: agents/faces split over frames, frames over scenes."""
    num_frames = draw(st.integers(0, 12))
    cuts = sorted(draw(st.lists(st.integers(0, num_frames), max_size=3)))
    bounds = [0, *cuts, num_frames]
    scenes = np.zeros(len(bounds) - 1, SCENE_DTYPE)
    scenes["frame_index_interval"] = np.stack([bounds[:-1], bounds[1:]], 1)
    scenes["host"] = draw(st.lists(st.text("abc-019", max_size=16), min_size=len(scenes), max_size=len(scenes)))
    frames = np.zeros(num_frames, FRAME_DTYPE)
    per_frame = np.array(draw(st.lists(st.integers(0, 4), min_size=num_frames, max_size=num_frames)), dtype=np.int64)
    ends = np.cumsum(per_frame)
    frames["agent_index_interval"] = np.stack([ends - per_frame, ends], 1)
    frames["traffic_light_faces_index_interval"] = np.stack([ends - per_frame, ends], 1)
    frames["timestamp"] = draw(st.lists(_int64, min_size=num_frames, max_size=num_frames)) if num_frames else 0
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    frames["ego_translation"] = rng.normal(size=(num_frames, 3)) * 1e3
    frames["ego_rotation"] = rng.normal(size=(num_frames, 3, 3))
    n = int(ends[-1]) if num_frames else 0
    agents = np.zeros(n, AGENT_DTYPE)
    for field in ("centroid", "extent", "yaw", "velocity", "label_probabilities"):
        agents[field] = rng.normal(size=agents[field].shape)
    agents["track_id"] = rng.integers(0, 2**63, size=n, dtype=np.uint64)
    faces = np.zeros(n, TL_FACE_DTYPE)
    faces["face_id"] = [f"f{i}" for i in range(n)]
    faces["traffic_light_id"] = "tl\u00e9"  # non-ASCII survives as UTF-32
    faces["traffic_light_face_status"] = rng.random((n, 3))
    chunks = {name: draw(st.integers(1, 5)) for name in ARRAY_NAMES}
    return (scenes, frames, agents, faces), chunks


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=_l5_arrays())
def test_round_trip_property(tmp_path_factory, data):
    arrays, chunks = data
    path = tmp_path_factory.mktemp("rt") / "s.zarr"
    write_l5_zarr(path, *arrays, chunk_sizes=chunks)
    back = L5Dataset.open(path).read_all()
    for name, ours, orig in zip(ARRAY_NAMES, back, arrays):
        assert ours.dtype == orig.dtype and ours.tobytes() == orig.tobytes(), name


def test_zarr_reads_what_we_write(tmp_path):
    zarr = pytest.importorskip("zarr")
    from pytest_driveeval.synth.scenegen import generate_scenes

    arrays = generate_scenes(2, 30, seed=3)
    path = write_l5_zarr(tmp_path / "s.zarr", *arrays, chunk_sizes={"agents": 100, "frames": 7})
    store = zarr.open(str(path), mode="r")
    assert store.attrs["labels"][3] == "PERCEPTION_LABEL_CAR"
    for name, orig in zip(ARRAY_NAMES, arrays):
        theirs = store[name][:]
        assert theirs.dtype == orig.dtype and theirs.tobytes() == orig.tobytes(), name


def test_rewrite_of_sample_matches_sample(sample, tmp_path):
    ours = L5Dataset.open(sample).read_all()
    write_l5_zarr(tmp_path / "s.zarr", *ours)
    for name in ARRAY_NAMES:  # same metadata as l5kit/zarr wrote, apart from JSON layout
        assert json.loads((tmp_path / "s.zarr" / name / ".zarray").read_text()) == \
            json.loads((sample / name / ".zarray").read_text()), name
    back = L5Dataset.open(tmp_path / "s.zarr").read_all()
    assert all(a.tobytes() == b.tobytes() for a, b in zip(ours, back))


def test_writer_refuses_to_clobber(tmp_path):
    arrays = (np.zeros(0, SCENE_DTYPE), np.zeros(0, FRAME_DTYPE), np.zeros(0, AGENT_DTYPE), np.zeros(0, TL_FACE_DTYPE))
    write_l5_zarr(tmp_path / "s.zarr", *arrays)
    with pytest.raises(FileExistsError):
        write_l5_zarr(tmp_path / "s.zarr", *arrays)
    write_l5_zarr(tmp_path / "s.zarr", *arrays, overwrite=True)
    assert L5Dataset.open(tmp_path / "s.zarr").num_scenes == 0


def track_table_by_rows(ids, frame, probabilities, num_frames):
    """The track table written row by row, as its docstring defines it."""
    track_ids = sorted(set(ids.tolist()))
    where = {t: i for i, t in enumerate(track_ids)}
    track = [where[t] for t in ids.tolist()]
    first = [num_frames] * len(track_ids)
    last = [-1] * len(track_ids)
    votes = np.zeros((len(track_ids), probabilities.shape[1]), np.int64)
    seen, repeated = set(), []
    for r, (a, f) in enumerate(zip(track, frame.tolist())):
        first[a], last[a] = min(first[a], f), max(last[a], f)
        votes[a, int(np.argmax(probabilities[r]))] += 1
        if (a, f) in seen:
            repeated.append(f)
        seen.add((a, f))
    return (np.array(track_ids, ids.dtype), np.array(track, np.int64), np.array(first, np.int64),
            np.array(last, np.int64), votes.argmax(axis=1), min(repeated, default=-1))


@pytest.mark.parametrize("sparse", [False, True])
@pytest.mark.parametrize("repeat", [False, True])
@pytest.mark.parametrize("seed", range(4))
def test_track_table_is_its_row_by_row_definition(seed, sparse, repeat):
    rows = random_rows(seed, sparse, repeat)
    got, expected = track_table(*rows), track_table_by_rows(*rows)
    assert (got.repeated_frame >= 0) == repeat
    for name, a, b in zip(got._fields, got, expected):
        assert np.array_equal(a, b) and np.asarray(a).dtype == np.asarray(b).dtype, name


def test_a_track_id_twice_in_one_frame_names_the_frame(tmp_path):
    from pytest_driveeval.synth.scenegen import generate_scenes

    scenes, frames, agents, faces = generate_scenes(1, 20, seed=0)
    a0, a1 = frames["agent_index_interval"][7]
    assert a1 - a0 >= 2
    agents["track_id"][a0 + 1] = agents["track_id"][a0]
    write_l5_zarr(tmp_path / "s.zarr", scenes, frames, agents, faces)
    scene = L5Dataset.open(tmp_path / "s.zarr").scene(0)
    with pytest.raises(L5FormatError, match=r"s\.zarr: scene 0: a track id occurs twice in one frame \(first at frame 7\)"):
        scene.agent_rows()


def test_chunks_decoded_into_evicted_buffers_read_the_same(tmp_path):
    # More chunks than the cache keeps, read forwards, backwards and at random: each chunk is
    # decoded into the buffer of one evicted before it.
    from pytest_driveeval.synth.scenegen import generate_scenes

    arrays = generate_scenes(6, 30, seed=2)
    write_l5_zarr(tmp_path / "s.zarr", *arrays, chunk_sizes={"agents": 37, "frames": 11})
    ds = L5Dataset.open(tmp_path / "s.zarr")
    agents = ds.read_array("agents")
    assert agents.tobytes() == arrays.agents.tobytes() and len(agents) > 20 * 37
    rng = np.random.default_rng(0)
    for start in [*range(0, len(agents), 29), *range(len(agents) - 1, 0, -53), *rng.integers(0, len(agents), 40)]:
        stop = min(len(agents), int(start) + int(rng.integers(1, 120)))
        assert ds.read_array("agents", int(start), stop).tobytes() == arrays.agents[start:stop].tobytes()


def test_a_corrupt_chunk_read_after_evictions_is_named(tmp_path):
    from pytest_driveeval.synth.scenegen import generate_scenes

    write_l5_zarr(tmp_path / "s.zarr", *generate_scenes(6, 30, seed=2), chunk_sizes={"agents": 37})
    (tmp_path / "s.zarr" / "agents" / "15").write_bytes(b"\x02\x01garbage" * 8)
    ds = L5Dataset.open(tmp_path / "s.zarr")
    ds.read_array("agents", 0, 14 * 37)  # fills the cache, so chunk 15 is decoded into an evicted buffer
    with pytest.raises(L5FormatError, match=r"agents/15: corrupt chunk 15 of array 'agents'"):
        ds.read_array("agents", 15 * 37, 16 * 37)
