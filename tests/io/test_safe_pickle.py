"""Pickles are read as data: arrays, dtypes and builtin containers, nothing else, and nothing run."""
import collections
import os
import pickle
import struct

import numpy as np
import pytest

from pytest_driveeval.core.errors import DataError
from pytest_driveeval.io.scenarionet.safe_pickle import UnsafePickleError, load_data_pickle

# a fast reader / score / report check: CI runs these at the lowest declared versions (-m smoke)
pytestmark = pytest.mark.smoke


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


# --------------------------------------------------------------------------- crafted pickles
# Each is a few KB at most, and refused before anything large is allocated.

def text(value: str) -> bytes:
    data = value.encode()
    return pickle.SHORT_BINUNICODE + bytes([len(data)]) + data


def name(module: str, attribute: str) -> bytes:
    return text(module) + text(attribute) + pickle.STACK_GLOBAL


def made(body: bytes, protocol: int = 4) -> bytes:
    return pickle.PROTO + bytes([protocol]) + body + pickle.STOP


def big_int(value: int) -> bytes:
    data = value.to_bytes((value.bit_length() + 8) // 8, "little", signed=True)
    return pickle.LONG1 + bytes([len(data)]) + data


def get(index: int) -> bytes:
    return pickle.BINGET + bytes([index]) if index < 256 else pickle.LONG_BINGET + struct.pack("<I", index)


def shared(item: bytes, fan_out: int, levels: int) -> bytes:
    """``item`` in a list of ``fan_out`` references, that list in one of ``fan_out`` references to it, ..."""
    body = item + pickle.MEMOIZE + pickle.POP
    for level in range(levels):
        body += pickle.EMPTY_LIST + pickle.MARK + get(level) * fan_out + pickle.APPENDS + pickle.MEMOIZE
        body += pickle.POP if level < levels - 1 else b""
    return body


def in_dict(key: str, value: bytes) -> bytes:
    return pickle.EMPTY_DICT + text(key) + value + pickle.SETITEM


def load_bytes(tmp_path, data: bytes, file="crafted.pkl"):
    path = tmp_path / file
    path.write_bytes(data)
    return load_data_pickle(path)


def test_a_few_kb_of_shared_references_that_expand_to_1e8_numbers_are_refused_naming_the_key(tmp_path):
    # 464 ** 3 = 1e8 floats (800 MB as an array, 3.7 GB while numpy converts the lists) from 3 KB
    data = made(in_dict("ts", shared(pickle.BINFLOAT + struct.pack(">d", 1.0), 464, 3)))
    assert len(data) < 5000
    with pytest.raises(UnsafePickleError, match=r"crafted.pkl is refused: at ts it unpacks to more than 512 MiB "
                                                r"\(shared references counted at each use"):
        load_bytes(tmp_path, data)


def test_a_list_of_1e4_references_to_a_list_of_1e4_arrays_is_refused(tmp_path):
    # np.zeros(1) as numpy writes it, once, and referred to
    f8 = (name("numpy", "dtype") + text("f8") + pickle.NEWFALSE + pickle.NEWTRUE + pickle.TUPLE3 + pickle.REDUCE
          + pickle.MARK + pickle.BININT1 + b"\x03" + text("<") + pickle.NONE * 3 + (pickle.BININT + b"\xff" * 4) * 2
          + pickle.BININT1 + b"\x00" + pickle.TUPLE + pickle.BUILD)
    array = (name("numpy._core.multiarray", "_reconstruct") + name("numpy", "ndarray") + pickle.BININT1 + b"\x00"
             + pickle.TUPLE1 + pickle.SHORT_BINBYTES + b"\x01b" + pickle.TUPLE3 + pickle.REDUCE
             + pickle.MARK + pickle.BININT1 + b"\x01" + pickle.BININT1 + b"\x01" + pickle.TUPLE1 + f8 + pickle.NEWFALSE
             + pickle.SHORT_BINBYTES + b"\x08" + b"\0" * 8 + pickle.TUPLE + pickle.BUILD)
    assert np.array_equal(load_bytes(tmp_path, made(array)), np.zeros(1))
    data = made(shared(array, 10_000, 2))
    with pytest.raises(UnsafePickleError, match="at the top it unpacks to more than 512 MiB"):
        load_bytes(tmp_path, data)
    # the same with 10 references is data like any other
    assert len(load_bytes(tmp_path, made(shared(array, 10, 2)))) == 10


@pytest.mark.parametrize("body, message", [
    (name("builtins", "bytearray") + big_int(3 << 30) + pickle.TUPLE1 + pickle.REDUCE,
     r"bytearray\(3221225472\) asks to allocate 3221225472 bytes that the file does not hold"),
    (name("builtins", "bytes") + big_int(3 << 30) + pickle.TUPLE1 + pickle.REDUCE,
     r"bytes\(3221225472\) asks to allocate"),
    (pickle.BYTEARRAY8 + struct.pack("<Q", 3 << 30) + b"\0" * 8, "declares a bytearray of 3221225472 bytes in a file"),
    (name("numpy", "ndarray") + big_int(30_000_000) + pickle.TUPLE1 + pickle.TUPLE1 + pickle.REDUCE,
     r"numpy.ndarray\(...\) called directly: it would allocate what the file asks"),
    (name("numpy._core.multiarray", "_reconstruct") + name("numpy", "ndarray") + big_int(30_000_000) + pickle.TUPLE1
     + pickle.SHORT_BINBYTES + b"\x01b" + pickle.TUPLE3 + pickle.REDUCE, "numpy writes an empty ndarray here"),
    (name("numpy", "float64") + pickle.EMPTY_LIST + pickle.TUPLE1 + pickle.REDUCE,
     r"numpy.float64\(list\): only 1 plain value"),
    (name("numpy", "dtype") + text("V3000000000") + pickle.TUPLE1 + pickle.REDUCE, r"numpy dtype |V3000000000"),
    (name("numpy._core.numeric", "_frombuffer") + pickle.MARK + pickle.SHORT_BINBYTES + b"\x08" + b"\0" * 8
     + name("numpy", "dtype") + text("f8") + pickle.TUPLE1 + pickle.REDUCE + big_int(10 ** 9) + pickle.TUPLE1
     + text("C") + pickle.TUPLE + pickle.REDUCE, r"numpy _frombuffer: 8 bytes for shape \(1000000000,\) of <f8"),
])
def test_a_size_the_file_asks_for_but_does_not_hold_is_refused_before_allocating(tmp_path, body, message):
    data = made(body, protocol=5)
    assert len(data) < 200
    with pytest.raises(UnsafePickleError, match=message):
        load_bytes(tmp_path, data)


@pytest.mark.parametrize("kind", ["OrderedDict", "defaultdict"])
def test_build_cannot_set_the_get_of_an_allowed_mapping(tmp_path, kind):
    # collections.OrderedDict() with {'get': ...} as its state: the standard unpickler sets the
    # instance's ``get``, and a reader's data.get("tracks") would call what the file chose
    data = made(name("collections", kind) + pickle.EMPTY_TUPLE + pickle.REDUCE
                + pickle.EMPTY_DICT + text("get") + name("builtins", "dict") + pickle.SETITEM + pickle.BUILD)
    with pytest.raises(UnsafePickleError, match=f"BUILD \\(setting attributes\\) on a {kind}: only numpy arrays and "
                                                "dtypes take state"):
        load_bytes(tmp_path, data)


def test_a_100000_deep_list_is_refused_with_its_key_and_a_cycle_too(tmp_path):
    deep = pickle.EMPTY_LIST * 100_000 + pickle.APPEND * 99_999
    with pytest.raises(UnsafePickleError, match=r"at id\[0\]\[0\]\[0\]\[0\]\[0\]\.\.\. \(33 levels\) it nests more "
                                                "than 32 levels deep"):
        load_bytes(tmp_path, made(in_dict("id", deep)))
    cycle = pickle.EMPTY_LIST + pickle.MEMOIZE + get(0) + pickle.APPEND
    with pytest.raises(UnsafePickleError, match=r"at tracks\[0\] it contains itself \(a cycle\)"):
        load_bytes(tmp_path, made(in_dict("tracks", cycle)))


def test_a_key_or_set_item_that_is_a_container_is_refused_before_it_is_hashed(tmp_path):
    # hashing a 3,000,000-deep tuple overflows the C stack: keys are plain values
    deep_tuple = pickle.EMPTY_TUPLE + pickle.TUPLE1 * 3
    with pytest.raises(UnsafePickleError, match="has a dict key that is a tuple: keys and set items must be plain"):
        load_bytes(tmp_path, made(pickle.EMPTY_DICT + deep_tuple + pickle.NONE + pickle.SETITEM))
    with pytest.raises(UnsafePickleError, match="has a set item that is a tuple"):
        load_bytes(tmp_path, made(pickle.MARK + deep_tuple + pickle.FROZENSET))


def test_an_object_of_a_class_or_a_type_as_data_is_refused(tmp_path):
    with pytest.raises(UnsafePickleError, match=r"makes an object of a class \(NEWOBJ"):
        load_bytes(tmp_path, made(name("builtins", "complex") + pickle.EMPTY_TUPLE + pickle.NEWOBJ))
    with pytest.raises(UnsafePickleError, match=r"at kind it holds numpy.float64 itself, a type, not data"):
        load_bytes(tmp_path, made(in_dict("kind", name("numpy", "float64"))))


def test_protocol_5_arrays_read_as_numpy_writes_them(tmp_path):
    value = {"a": np.arange(6, dtype=np.float32).reshape(2, 3), "f": np.asfortranarray(np.eye(3))}
    back = load_bytes(tmp_path, pickle.dumps(value, protocol=5))
    assert np.array_equal(back["a"], value["a"]) and back["a"].dtype == np.float32
    assert np.array_equal(back["f"], value["f"])


def test_only_regular_files_up_to_the_stated_size_are_read(tmp_path, monkeypatch):
    import pytest_driveeval.io.scenarionet.safe_pickle as safe_pickle

    zero = tmp_path / "sd_zero.pkl"
    zero.symlink_to("/dev/zero")
    with pytest.raises(DataError, match=r"sd_zero.pkl \(a link to /dev/zero\) is a character device, not a regular "
                                        "file: only regular files are read as data"):
        load_data_pickle(zero)
    pipe = tmp_path / "sd_pipe.pkl"
    os.mkfifo(pipe)
    with pytest.raises(DataError, match=r"sd_pipe.pkl is a FIFO \(pipe\), not a regular file"):  # and did not wait
        load_data_pickle(pipe)
    gone = tmp_path / "sd_gone.pkl"
    gone.symlink_to(tmp_path / "nowhere.pkl")
    with pytest.raises(DataError, match=r"sd_gone.pkl cannot be read \(a link whose target is missing\)"):
        load_data_pickle(gone)
    monkeypatch.setattr(safe_pickle, "MAX_FILE_BYTES", 1000)
    big = tmp_path / "sd_big.pkl"
    big.write_bytes(pickle.dumps(np.zeros(200), protocol=4))
    with pytest.raises(DataError, match=r"sd_big.pkl is 0.00167 MiB, more than the 0.000954 MiB a data file may be"):
        load_data_pickle(big)
