"""What a data pickle may build, and with which arguments: the callables :mod:`.safe_pickle` lets a
pickle name, each checking its arguments before it builds anything.

A pickle calls what it names with arguments it chooses: ``bytearray(3 << 30)`` or
``numpy.ndarray((3e7,))`` ask for gigabytes in a few bytes, ``numpy.float64([...])`` turns a list
of shared references into an array as large as they expand to, and ``str(x)`` of a nested list
recurses.  So each allowed name is a :class:`Maker` that accepts only the arguments the pickles of
numpy and Python write (numpy: ``_reconstruct(ndarray, (0,), b'b')`` then BUILD with the data,
``dtype('f8', False, True)``, ``scalar(dtype, bytes)``, protocol 5's ``_frombuffer(buffer, dtype,
shape, order)``; builtins: ``complex(1.0, 2.0)``, ``bytearray(b'..')``, ``set([...])``, ...), and
every size it builds is one the file's own bytes hold.
"""
from __future__ import annotations

import collections
import importlib
import math
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

#: the largest numpy item (a string dtype of 16 Ki characters): ScenarioNet's strings are ids and names
MAX_ITEMSIZE = 1 << 16
#: numpy kinds a data file's arrays may have: bool, integers, floats, complex, text, bytes, objects
#: (an object array holds what the pickle built, each item checked as any other)
ARRAY_KINDS = "biufcUSO"
MAX_DIMS = 32


class Refused(Exception):
    """A call or state the file asks for that is not data; the loader names the file."""


@dataclass(frozen=True)
class Maker:
    """An allowed ``module.name``: ``value`` is what it names (passed as an argument, e.g. the
    ``ndarray`` of ``_reconstruct(ndarray, ...)``), ``call`` builds it from checked arguments."""

    name: str
    value: Any
    call: Callable[..., Any]

    def __repr__(self) -> str:
        return self.name


#: numpy's major version: 2 moved ``numpy.core`` to ``numpy._core``
NUMPY_MAJOR = int(np.__version__.split(".")[0])
#: the installed numpy's own module path for its pickle reconstructors.  Pickles name either path
#: (numpy 1 writes ``numpy.core``, numpy 2 ``numpy._core``); both are served by the installed one, so
#: neither numpy 2's deprecated ``numpy.core`` alias (it warns) nor numpy 1.26's ``numpy._core``
#: stub (whose submodules ``import numpy`` does not load) is touched.
NUMPY_CORE = "numpy._core" if NUMPY_MAJOR >= 2 else "numpy.core"
#: both spellings a pickle may use for the modules below
NUMPY_CORE_NAMES = ("numpy.core", "numpy._core")


def _multiarray() -> Any:
    return importlib.import_module(f"{NUMPY_CORE}.multiarray")


SCALARS = (type(None), bool, int, float, complex, str, bytes, np.generic)


def is_scalar(value: Any) -> bool:
    """A value that hashes and prints without recursing into anything the file built."""
    return isinstance(value, SCALARS)


def _scalar_args(name: str, args: tuple, most: int) -> None:
    if len(args) > most or not all(is_scalar(a) for a in args):
        shown = ", ".join(type(a).__name__ for a in args)
        raise Refused(f"{name}({shown}): only {most} plain value(s) (numbers, text, bytes) may be passed to it")


def _items(name: str, args: tuple, hashed: bool) -> tuple:
    if not args:
        return ()
    if len(args) != 1 or not isinstance(args[0], (list, tuple)):
        raise Refused(f"{name}(...): takes one list of items, as pickle writes it")
    items = args[0]
    if hashed and not all(is_scalar(i) for i in items):
        raise Refused(f"{name}(...): its items must be plain values (numbers, text, bytes); hashing anything "
                      "else the file built can recurse without bound")
    return items


def _bytes_of(name: str, args: tuple) -> Any:
    if not args:
        return b""
    if len(args) == 1 and isinstance(args[0], (bytes, bytearray)):
        return args[0]
    if len(args) == 1 and isinstance(args[0], int) and not isinstance(args[0], bool):
        raise Refused(f"{name}({args[0]}) asks to allocate {args[0]} bytes that the file does not hold; "
                      "a data file gives its bytes")
    raise Refused(f"{name}(...): takes the bytes themselves")


def _builtin(kind: type) -> Maker:
    name = f"builtins.{kind.__name__}"
    if kind in (bytes, bytearray):
        return Maker(name, kind, lambda *args: kind(_bytes_of(name, args)))
    if kind in (set, frozenset):
        return Maker(name, kind, lambda *args: kind(_items(name, args, hashed=True)))
    if kind in (list, tuple):
        return Maker(name, kind, lambda *args: kind(_items(name, args, hashed=False)))
    if kind is dict:
        return Maker(name, kind, lambda *args: _scalar_args(name, args, 0) or {})

    def scalar(*args: Any) -> Any:
        _scalar_args(name, args, 2 if kind is complex else 1)
        return kind(*args)

    return Maker(name, kind, scalar)


BUILTINS = {kind: _builtin(kind) for kind in (dict, list, tuple, set, frozenset, int, float, complex, str, bytes,
                                              bytearray, bool)}


def _defaultdict(factory: Any = None, *rest: Any) -> collections.defaultdict:
    if rest or not (factory is None or isinstance(factory, Maker) and factory in BUILTINS.values()):
        raise Refused("collections.defaultdict(...): its default may only be a builtin type (list, dict, ...)")
    return collections.defaultdict(None if factory is None else factory.value)


def _ordered_dict(*args: Any) -> collections.OrderedDict:
    _scalar_args("collections.OrderedDict", args, 0)
    return collections.OrderedDict()


def check_dtype(dtype: Any, what: str) -> np.dtype:
    if not isinstance(dtype, np.dtype):
        raise Refused(f"{what}: {type(dtype).__name__} where a numpy dtype belongs")
    if dtype.fields is not None or dtype.subdtype is not None or dtype.kind not in ARRAY_KINDS:
        raise Refused(f"{what}: numpy dtype {dtype.str} (structured, a subarray or of kind {dtype.kind!r}); "
                      "ScenarioNet's arrays are plain numbers, text or objects")
    if dtype.itemsize > MAX_ITEMSIZE:
        raise Refused(f"{what}: numpy dtype {dtype.str} has items of {dtype.itemsize} bytes, more than "
                      f"{MAX_ITEMSIZE}")
    return dtype


def _dtype(spec: Any, align: Any = False, copy: Any = True) -> np.dtype:
    if not isinstance(spec, str) or len(spec) > 16:
        raise Refused(f"numpy.dtype({type(spec).__name__}): a dtype is named by a short text such as 'f8'")
    try:
        made = np.dtype(spec, bool(align), True)  # a copy always: BUILD then sets its state, not numpy's own
    except (TypeError, ValueError) as exc:
        raise Refused(f"numpy.dtype({spec!r}): {exc}") from None
    return check_dtype(made, f"numpy.dtype({spec!r})")


def _size(shape: Any, what: str) -> int:
    if not isinstance(shape, tuple) or len(shape) > MAX_DIMS or not all(
            isinstance(n, int) and not isinstance(n, bool) and n >= 0 for n in shape):
        raise Refused(f"{what}: shape {shape!r} is not a tuple of up to {MAX_DIMS} sizes >= 0")
    return math.prod(shape)


def _reconstruct(subtype: Any, shape: Any, dtype: Any) -> np.ndarray:
    if subtype is not MAKERS[("numpy", "ndarray")] or _size(shape, "_reconstruct") != 0:
        raise Refused(f"numpy _reconstruct({subtype!r}, {shape!r}, ...): numpy writes an empty ndarray here "
                      "and its data after (BUILD)")
    return _multiarray()._reconstruct(np.ndarray, (0,), b"b")


def _scalar(dtype: Any, data: Any = None) -> Any:
    dtype = check_dtype(dtype, "numpy scalar")
    if dtype.hasobject:
        if not is_scalar(data):
            raise Refused("numpy object scalar: holds a plain value only")
    elif not isinstance(data, bytes) or len(data) != dtype.itemsize:
        raise Refused(f"numpy scalar of {dtype.str}: needs its {dtype.itemsize} bytes")
    return _multiarray().scalar(dtype, data)


def _frombuffer(buffer: Any, dtype: Any, shape: Any, order: Any = "C") -> np.ndarray:
    dtype = check_dtype(dtype, "numpy _frombuffer")
    size = _size(shape, "numpy _frombuffer")
    if dtype.hasobject or not isinstance(buffer, (bytes, bytearray)) or len(buffer) != size * dtype.itemsize \
            or order not in ("C", "F"):
        raise Refused(f"numpy _frombuffer: {len(buffer) if isinstance(buffer, (bytes, bytearray)) else '?'} bytes "
                      f"for shape {shape} of {dtype.str}: they must match")
    return np.frombuffer(buffer, dtype).reshape(shape, order=order)


def _direct(name: str) -> Callable[..., Any]:
    def refuse(*args: Any) -> Any:
        raise Refused(f"{name}(...) called directly: it would allocate what the file asks, not what it holds "
                      "(numpy writes arrays through _reconstruct and their bytes)")

    return refuse


def _numpy_scalar_type(kind: type) -> Maker:
    name = f"numpy.{kind.__name__}"

    def call(*args: Any) -> Any:
        _scalar_args(name, args, 1)
        return kind(*args)

    return Maker(name, kind, call)


MAKERS: dict[tuple[str, str], Maker] = {
    ("numpy", "ndarray"): Maker("numpy.ndarray", np.ndarray, _direct("numpy.ndarray")),
    ("numpy", "dtype"): Maker("numpy.dtype", np.dtype, _dtype),
    ("collections", "defaultdict"): Maker("collections.defaultdict", collections.defaultdict, _defaultdict),
    ("collections", "OrderedDict"): Maker("collections.OrderedDict", collections.OrderedDict, _ordered_dict),
    **{("builtins", kind.__name__): maker for kind, maker in BUILTINS.items()},
    # numpy's scalar types, as dtype(...) and scalar(...) name them in older pickles
    **{("numpy", t.__name__): _numpy_scalar_type(t)
       for t in (np.float64, np.float32, np.float16, np.int64, np.int32, np.int16, np.int8,
                 np.uint64, np.uint32, np.uint16, np.uint8, np.bool_, np.str_, np.bytes_)},
}
for _module in NUMPY_CORE_NAMES:
    MAKERS[(f"{_module}.multiarray", "_reconstruct")] = Maker("numpy _reconstruct", None, _reconstruct)
    MAKERS[(f"{_module}.multiarray", "scalar")] = Maker("numpy scalar", None, _scalar)
    MAKERS[(f"{_module}.numeric", "_frombuffer")] = Maker("numpy _frombuffer", None, _frombuffer)


def build(inst: Any, state: Any) -> None:
    """BUILD: set ``state`` on ``inst``, for numpy arrays and dtypes only.  On anything else it
    would set attributes: an ``OrderedDict`` whose ``get`` is the file's."""
    if isinstance(inst, np.dtype):
        # (version, byte order, subarray, names, fields, item size, alignment, flags): plain dtypes only
        if not isinstance(state, tuple) or len(state) != 8 or any(s is not None for s in state[2:5]) \
                or not all(isinstance(s, int) for s in state[5:]):
            raise Refused("a numpy dtype's state that is not a plain dtype's")
        inst.__setstate__(state)
        check_dtype(inst, "numpy dtype")
        return
    if isinstance(inst, np.ndarray):
        if not isinstance(state, tuple) or len(state) not in (4, 5):
            raise Refused("a numpy array's state that is not (version, shape, dtype, fortran, data)")
        shape, dtype, fortran, data = state[-4:]
        size = _size(shape, "numpy array")
        dtype = check_dtype(dtype, "numpy array")
        if dtype.hasobject:
            if not isinstance(data, list) or len(data) != size:
                raise Refused(f"a numpy object array of shape {shape} given {type(data).__name__} items")
        elif not isinstance(data, (bytes, bytearray)) or len(data) != size * dtype.itemsize:
            held = len(data) if isinstance(data, (bytes, bytearray)) else type(data).__name__
            raise Refused(f"a numpy array of shape {shape} of {dtype.str} needs {size * dtype.itemsize} bytes; "
                          f"the file gives {held}")
        inst.__setstate__(state)
        return
    raise Refused(f"BUILD (setting attributes) on a {type(inst).__name__}: only numpy arrays and dtypes take "
                  "state from a data file")
