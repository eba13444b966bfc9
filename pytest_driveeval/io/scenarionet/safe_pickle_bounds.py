"""How large and how deep a loaded data pickle is, counted before any reader converts it.

A pickle refers to an object it built before by its memo number: a few bytes each.  A list of
1,000 references to a list of 1,000 references to a list of 1,000 numbers is about 6 KB of pickle,
and ``numpy.asarray`` of it is 1e9 numbers (8 GB, more while it converts).  A list 100,000 deep is
300 KB, and ``str`` or ``repr`` of it is a ``RecursionError``; a cycle never ends.  So the object
the unpickler built is measured as any reader would expand it: every container's size counts its
items each time they are used, shared or not (:data:`MAX_UNPACKED_BYTES`), and its nesting is at
most :data:`MAX_DEPTH`.  Each object is visited once (its expanded size is remembered), so the
count costs what the file holds, not what it expands to.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from .safe_pickle_makers import Maker, Refused

#: bytes a file may unpack to, counting shared references at each use: 8 per number or slot,
#: an array's data, a text's characters (ScenarioNet's scenes unpack to a few MB)
MAX_UNPACKED_BYTES = 512 << 20
#: containers within containers: ScenarioNet nests 6 deep (tracks -> id -> state -> position ...)
MAX_DEPTH = 32
SLOT = 8


def _children(value: Any) -> Any:
    """An iterator of (key for the path, child) of a container; None for anything else."""
    if isinstance(value, dict):
        return iter(value.items())
    if isinstance(value, (list, tuple)):
        return enumerate(value)
    if isinstance(value, (set, frozenset)):
        return ((None, v) for v in value)
    if isinstance(value, np.ndarray) and value.dtype.hasobject:
        return enumerate(value.ravel().tolist())
    return None


def _own_size(value: Any) -> int:
    if isinstance(value, np.ndarray):
        return max(value.nbytes, SLOT)
    if isinstance(value, (str, bytes, bytearray)):
        return max(len(value), SLOT)
    if isinstance(value, (dict, list, tuple, set, frozenset)):
        return SLOT * (1 + 2 * len(value) if isinstance(value, dict) else 1 + len(value))
    return SLOT


def path_text(path: list) -> str:
    """A key path as a reader writes it: ``tracks.ego.state.position[3]``."""
    out = ""
    for part in path:
        if isinstance(part, int):
            out += f"[{part}]"
        elif part is None:
            out += ".<item>"
        else:
            out += f".{part}" if out else str(part)
    return out or "the top"


def _short(path: list) -> str:
    return path_text(path[:6]) + (f"... ({len(path)} levels)" if len(path) > 6 else "")


def check_bounds(value: Any, max_bytes: int = MAX_UNPACKED_BYTES, max_depth: int = MAX_DEPTH) -> int:
    """The bytes ``value`` unpacks to (shared references counted at each use); :class:`Refused`,
    naming the key path, for a cycle, more than ``max_depth`` levels, more than ``max_bytes``, or a
    callable left in the data."""
    def too_large(path: list) -> Refused:
        return Refused(f"at {_short(path)} it unpacks to more than {max_bytes >> 20} MiB (shared references counted "
                       "at each use, as a reader expands them), the most a data file may")

    if isinstance(value, Maker):
        raise Refused(f"it is {value.name} itself, a type, not data")
    sizes: dict[int, int] = {}
    keep: list[Any] = []  # ids are only unique while their objects live
    on_path: set[int] = {id(value)}
    plain = (float, int, bool, type(None))
    # [container, its key path, iterator over its children, its size so far]
    stack: list[list[Any]] = [[value, [], _children(value) or iter(()), _own_size(value)]]
    while stack:
        frame = stack[-1]
        node, path, children, total = frame
        deeper = None
        for key, child in children:
            if type(child) in plain:  # most of a scene: its numbers
                total += SLOT
            else:
                known = sizes.get(id(child))
                if known is None:
                    if isinstance(child, Maker):
                        raise Refused(f"at {_short(path + [key])} it holds {child.name} itself, a type, not data")
                    if type(child) in (tuple, list) and len(path) < max_depth \
                            and all(type(item) in plain for item in child):  # a point, a row: no frame
                        known = sizes[id(child)] = SLOT * (1 + 2 * len(child))
                        keep.append(child)
                        total += known
                        if total > max_bytes:
                            raise too_large(path)
                        continue
                    grandchildren = _children(child)
                    if grandchildren is not None:
                        deeper = [child, path + [key], grandchildren, _own_size(child)]
                        break
                    known = _own_size(child)
                total += known
            if total > max_bytes:
                raise too_large(path)
        frame[3] = total
        if deeper is not None:
            if id(deeper[0]) in on_path:
                raise Refused(f"at {_short(deeper[1])} it contains itself (a cycle): no reader can expand it")
            if len(deeper[1]) > max_depth:
                raise Refused(f"at {_short(deeper[1])} it nests more than {max_depth} levels deep: no ScenarioNet "
                              "value does, and readers recurse through it")
            on_path.add(id(deeper[0]))
            stack.append(deeper)
            continue
        stack.pop()
        on_path.discard(id(node))
        sizes[id(node)] = total
        keep.append(node)
        if stack:
            stack[-1][3] += total
            if stack[-1][3] > max_bytes:
                raise too_large(stack[-1][1])
    return sizes[id(value)]
