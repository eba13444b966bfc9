"""Pickles are read as data: arrays, dtypes and builtin containers, nothing else, and nothing run."""
import collections
import os
import pickle

import numpy as np
import pytest

from pytest_driveeval.io.scenarionet.safe_pickle import UnsafePickleError, load_data_pickle


class Boom:
    def __reduce__(self):
        return (os.system, ("echo pwned > pwned.txt",))


def test_arrays_dtypes_and_builtin_containers_come_back_equal(tmp_path):
    value = {"a": np.arange(6, dtype=np.float32).reshape(2, 3), "s": {1, 2}, "t": (1.5, "x", None, True),
             "d": collections.defaultdict(list, {"k": [np.int64(3)]}), "o": collections.OrderedDict(z=b"\x00"),
             "strings": np.array(["GO", "STOP"]), "scalar": np.float64(2.5), "c": 1 + 2j}
    path = tmp_path / "ok.pkl"
    path.write_bytes(pickle.dumps(value, protocol=4))
    back = load_data_pickle(path)
    assert back.keys() == value.keys()
    assert np.array_equal(back["a"], value["a"]) and back["a"].dtype == np.float32
    assert back["d"]["k"] == [3] and isinstance(back["d"], collections.defaultdict)
    assert list(back["strings"]) == ["GO", "STOP"] and back["scalar"] == 2.5 and back["s"] == {1, 2}


def test_a_pickle_naming_any_other_callable_is_refused_by_name_and_nothing_runs(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    path = tmp_path / "evil.pkl"
    path.write_bytes(pickle.dumps({"tracks": Boom()}, protocol=4))
    with pytest.raises(UnsafePickleError, match=r"evil.pkl asks for (posix|os)\.system, which a data file may not name"):
        load_data_pickle(path)
    assert not (tmp_path / "pwned.txt").exists()


@pytest.mark.parametrize("data, reason", [
    (b"not a pickle at all", "is not a pickle"),
    (pickle.dumps({"a": np.zeros(100)}, protocol=4)[:-40], "truncated"),
    (b"", "is not a pickle"),
])
def test_a_truncated_or_foreign_file_is_an_error_naming_it(tmp_path, data, reason):
    path = tmp_path / "bad.pkl"
    path.write_bytes(data)
    with pytest.raises(UnsafePickleError, match=f"bad.pkl .*{reason}|bad.pkl {reason}"):
        load_data_pickle(path)
