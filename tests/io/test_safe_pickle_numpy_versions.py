"""numpy 1 and numpy 2 pickles both load, on whichever numpy is installed, and nothing more is admitted.

numpy 1 names its reconstructors ``numpy.core.multiarray`` / ``numpy.core.numeric``, numpy 2
``numpy._core...``.  The pickles here are written opcode by opcode (not by the installed numpy's
``pickle.dumps``) so that each spelling is tested whatever numpy runs the test.
"""
import pickle
import struct
import subprocess
import sys
import warnings

import numpy as np
import pytest

from pytest_driveeval.io.scenarionet.safe_pickle import ALLOWED, UnsafePickleError, load_data_pickle

CORE_NAMES = ["numpy.core", "numpy._core"]


def text(value: str) -> bytes:
    data = value.encode()
    return pickle.SHORT_BINUNICODE + bytes([len(data)]) + data


def name(module: str, attribute: str) -> bytes:
    return text(module) + text(attribute) + pickle.STACK_GLOBAL


def made(body: bytes, protocol: int) -> bytes:
    return pickle.PROTO + bytes([protocol]) + body + pickle.STOP


def f8() -> bytes:
    """``numpy.dtype('f8', False, True)`` and its BUILD state, as both numpys write it."""
    return (name("numpy", "dtype") + text("f8") + pickle.NEWFALSE + pickle.NEWTRUE + pickle.TUPLE3 + pickle.REDUCE
            + pickle.MARK + pickle.BININT1 + b"\x03" + text("<") + pickle.NONE * 3 + (pickle.BININT + b"\xff" * 4) * 2
            + pickle.BININT1 + b"\x00" + pickle.TUPLE + pickle.BUILD)


def array_pickle(core: str, values: list[float]) -> bytes:
    """``np.array(values)`` as ``pickle.dumps(..., protocol=4)`` writes it, under ``core``."""
    data = struct.pack(f"<{len(values)}d", *values)
    return made(name(f"{core}.multiarray", "_reconstruct") + name("numpy", "ndarray") + pickle.BININT1 + b"\x00"
                + pickle.TUPLE1 + pickle.SHORT_BINBYTES + b"\x01b" + pickle.TUPLE3 + pickle.REDUCE
                + pickle.MARK + pickle.BININT1 + b"\x01" + pickle.BININT1 + bytes([len(values)]) + pickle.TUPLE1
                + f8() + pickle.NEWFALSE + pickle.SHORT_BINBYTES + bytes([len(data)]) + data
                + pickle.TUPLE + pickle.BUILD, protocol=4)


def scalar_pickle(core: str, value: float) -> bytes:
    """``np.float64(value)`` as numpy writes it: ``scalar(dtype, its 8 bytes)``."""
    return made(name(f"{core}.multiarray", "scalar") + f8() + pickle.SHORT_BINBYTES + b"\x08"
                + struct.pack("<d", value) + pickle.TUPLE2 + pickle.REDUCE, protocol=4)


def frombuffer_pickle(core: str, values: list[float]) -> bytes:
    """``np.array(values)`` as protocol 5 writes it: ``_frombuffer(bytes, dtype, shape, order)``."""
    data = struct.pack(f"<{len(values)}d", *values)
    return made(name(f"{core}.numeric", "_frombuffer") + pickle.MARK + pickle.SHORT_BINBYTES + bytes([len(data)])
                + data + f8() + pickle.BININT1 + bytes([len(values)]) + pickle.TUPLE1 + text("C") + pickle.TUPLE
                + pickle.REDUCE, protocol=5)


def load(tmp_path, data: bytes):
    path = tmp_path / "scene.pkl"
    path.write_bytes(data)
    with warnings.catch_warnings():
        # numpy 2's numpy.core alias warns when touched: loading a numpy 1 pickle must not touch it
        warnings.simplefilter("error", DeprecationWarning)
        return load_data_pickle(path)


@pytest.mark.smoke
@pytest.mark.parametrize("core", CORE_NAMES)
def test_an_array_written_by_either_numpy_loads_on_the_installed_one(tmp_path, core):
    back = load(tmp_path, array_pickle(core, [1.5, -2.0, 3.25]))
    assert isinstance(back, np.ndarray) and back.dtype == np.float64
    assert back.tolist() == [1.5, -2.0, 3.25]


@pytest.mark.parametrize("core", CORE_NAMES)
def test_a_scalar_written_by_either_numpy_loads_on_the_installed_one(tmp_path, core):
    back = load(tmp_path, scalar_pickle(core, 2.5))
    assert isinstance(back, np.float64) and back == 2.5


@pytest.mark.parametrize("core", CORE_NAMES)
def test_a_protocol_5_array_written_by_either_numpy_loads_on_the_installed_one(tmp_path, core):
    assert load(tmp_path, frombuffer_pickle(core, [4.0, 5.0])).tolist() == [4.0, 5.0]


def test_exactly_the_reconstructors_are_admitted_under_both_names():
    numpy_core = {(module, attr) for module, attr in ALLOWED if module.startswith(("numpy.core", "numpy._core"))}
    assert numpy_core == {(f"{core}.{module}", attr) for core in CORE_NAMES
                          for module, attr in [("multiarray", "_reconstruct"), ("multiarray", "scalar"),
                                               ("numeric", "_frombuffer")]}


@pytest.mark.smoke
@pytest.mark.parametrize("core", CORE_NAMES)
@pytest.mark.parametrize("attribute", ["_reconstruct", "system"])
def test_os_system_or_another_global_under_either_name_is_refused(tmp_path, core, attribute):
    # os.system named as it is, and an unlisted attribute of numpy's own module under either name
    module = "os" if attribute == "system" else f"{core}.umath"
    data = made(name(module, attribute) + text("echo pwned") + pickle.TUPLE1 + pickle.REDUCE, protocol=4)
    with pytest.raises(UnsafePickleError, match=f"asks for {module}.{attribute}, which a data file may not name"):
        load(tmp_path, data)


def test_reading_a_numpy_1_pickle_imports_neither_the_other_numpy_layout_nor_the_alias():
    # numpy 1 has no numpy._core.multiarray to import (1.26 ships a stub package); numpy 2's numpy.core
    # is a deprecated alias.  A fresh interpreter shows which module a load imported.
    script = f"""
import sys, tempfile, pathlib, numpy
from pytest_driveeval.io.scenarionet.safe_pickle import load_data_pickle
path = pathlib.Path(tempfile.mkdtemp()) / "scene.pkl"
other = "numpy._core.multiarray" if int(numpy.__version__.split(".")[0]) < 2 else "numpy.core.multiarray"
before = other in sys.modules
for data in ({array_pickle("numpy.core", [1.0])!r}, {array_pickle("numpy._core", [1.0])!r}):
    path.write_bytes(data)
    assert load_data_pickle(path).tolist() == [1.0]
print(before or other not in sys.modules)
"""
    done = subprocess.run([sys.executable, "-W", "error::DeprecationWarning", "-c", script], capture_output=True,
                          text=True)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "True"
