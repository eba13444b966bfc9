"""The executor without Ray: the spec, the option, splitting, the local path, errors, progress."""
from __future__ import annotations

import sys

import numpy as np
import pytest
from pydantic import ValidationError

from pytest_driveeval.core.errors import DataError, DriveEvalError
from pytest_driveeval.execute import (ChunkError, ExecutorError, ExecutorSpec, executor_from_option, run_chunks, split)

LOCAL = ExecutorSpec()


def scene_sums(chunk):
    """A chunk's scenes as seeded draws: its result depends on its own description only."""
    seed, scenes = chunk
    return np.stack([np.random.default_rng((seed, s)).normal(size=64).cumsum() for s in scenes])


def scaled(chunk, shared):
    return shared["scale"] * np.asarray(chunk)


def fails_on_two(chunk):
    if chunk == 2:
        raise ValueError("scene 2 has no ego track")
    return chunk * 10


def data_error_on_one(chunk):
    if chunk == 1:
        raise DataError("scenes.zarr: frame 7 is truncated")
    return chunk


def test_the_spec_defaults_to_local_and_checks_its_keys():
    assert LOCAL.is_local and LOCAL.Retries == 3 and LOCAL.describe() == "local"
    spec = ExecutorSpec(Kind="ray", Address="ray://head.example:10001", ChunkSize=64, NumCpus=0.5)
    assert not spec.is_local and spec.describe() == "ray (ray://head.example:10001)"
    for address in ("auto", "local", "10.0.0.4:6379", "[::1]:6379"):
        assert ExecutorSpec(Kind="ray", Address=address).Address == address
    with pytest.raises(ValidationError, match="Address"):
        ExecutorSpec(Kind="ray", Address="http://head:8265")
    with pytest.raises(ValidationError, match="ChunkSize"):
        ExecutorSpec(ChunkSize=0)
    with pytest.raises(ValidationError, match="Chunksize"):
        ExecutorSpec.model_validate({"Kind": "ray", "Chunksize": 8})


def test_the_session_option_reads_a_word_or_the_scenarios_mapping():
    assert executor_from_option("ray").Kind == "ray"
    assert executor_from_option(" local ").is_local
    spec = executor_from_option("{Kind: ray, Address: auto, ChunkSize: 32, MaxInFlight: 8}")
    assert (spec.Kind, spec.Address, spec.ChunkSize, spec.MaxInFlight) == ("ray", "auto", 32, 8)
    with pytest.raises(ValueError, match="Kind"):
        executor_from_option("{Kind: dask}")
    with pytest.raises(ValueError, match="neither local, ray nor a YAML mapping"):
        executor_from_option("rays")
    with pytest.raises(ValueError, match="neither local, ray nor a YAML mapping"):
        executor_from_option("{Kind: ray")


def test_split_covers_every_item_once_in_order():
    chunks = split(10, 4)
    assert chunks == [range(0, 4), range(4, 8), range(8, 10)]
    assert [i for c in split(1000, 7) for i in c] == list(range(1000))
    assert split(0, 5) == []
    with pytest.raises(ValueError):
        split(5, 0)


def test_the_local_path_runs_in_order_and_reports_where():
    work = [(7, c) for c in split(10, 3)]
    seen = []
    run = run_chunks(LOCAL, work, scene_sums, progress=lambda done, total: seen.append((done, total)))
    whole = scene_sums((7, range(10)))
    assert np.array_equal(np.concatenate(run.results), whole)
    assert seen == [(0, 4), (1, 4), (2, 4), (3, 4), (4, 4)]
    assert [p.chunk for p in run.placements] == [0, 1, 2, 3]
    assert run.nodes == {"local"} and run.retried == []
    assert run.summary().startswith("4 chunks on local")


def test_shared_data_reaches_every_chunk():
    run = run_chunks(LOCAL, [[1, 2], [3]], scaled, shared={"scale": 2.5})
    assert [r.tolist() for r in run.results] == [[2.5, 5.0], [7.5]]


def test_a_failing_chunk_is_named_and_the_finished_ones_are_kept():
    with pytest.raises(ChunkError) as caught:
        run_chunks(LOCAL, [0, 1, 2, 3], fails_on_two)
    error = caught.value
    assert error.chunk == 2 and isinstance(error.cause, ValueError)
    assert error.results == {0: 0, 1: 10} and sorted(error.placements) == [0, 1]
    message = str(error)
    assert "chunk 2 of 4 (2) failed" in message and "scene 2 has no ego track" in message
    # a bug, not the user's input: its traceback is in the message, as a DriveEvalError hides it
    assert "fails_on_two" in message and "Traceback" in message
    assert isinstance(error, DriveEvalError)


def test_a_data_error_in_a_chunk_stays_short_and_keeps_its_class():
    with pytest.raises(ChunkError) as caught:
        run_chunks(LOCAL, [0, 1, 2], data_error_on_one)
    assert isinstance(caught.value.cause, DataError)
    assert "frame 7 is truncated" in str(caught.value) and "Traceback" not in str(caught.value)


def test_task_fn_must_be_sendable_by_name():
    with pytest.raises(TypeError, match="module-level"):
        run_chunks(LOCAL, [1], lambda chunk: chunk)

    def inner(chunk):
        return chunk

    with pytest.raises(TypeError, match="module-level"):
        run_chunks(LOCAL, [1], inner)




def test_kind_ray_without_ray_says_how_to_install_it(monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)   # as if not installed
    with pytest.raises(ExecutorError, match=r"pip install 'pytest-driveeval\[ray\]'"):
        run_chunks(ExecutorSpec(Kind="ray"), [1], scaled, shared={"scale": 1})
