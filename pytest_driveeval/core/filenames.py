"""Text from the data (a scenario id, a benchmark id, a file name) as part of a file name we write."""
from __future__ import annotations

import re

#: long enough for a Waymo or nuPlan scenario id or a CommonRoad benchmark id, short enough that a
#: name made of a few of them stays inside every file system's 255-byte limit
NAME_PART_MAX = 60
_UNSAFE = re.compile(r"[^A-Za-z0-9._-]+")


def safe_name_part(text: str, limit: int = NAME_PART_MAX) -> str:
    """``text`` as part of a file name: no path separator, nothing a shell or file system treats
    specially (each run of such characters becomes one ``_``), no leading dot (a hidden file), at
    most ``limit`` characters (a long one keeps its start and its end, joined by ``~``)."""
    safe = _UNSAFE.sub("_", text).strip("._") or "_"
    if len(safe) > limit:
        keep = (limit - 1) // 2
        safe = f"{safe[:keep]}~{safe[-(limit - 1 - keep):]}"
    return safe
