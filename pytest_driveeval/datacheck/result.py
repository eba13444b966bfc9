"""What checking one file found: what was read, what was skipped and why, and whether the file can be
evaluated (the reasons it cannot, each naming the file and the element at fault)."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

from pytest_driveeval.core.errors import display_path

#: the attributes a reader's object may list what it left out in (see :func:`skipped_entries`)
SKIPPED_ATTRIBUTES = ("skipped",)


@dataclass
class FileCheck:
    path: Path
    format: str
    read: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """True when the file can be evaluated (what was skipped does not stop it)."""
        return not self.problems

    def to_json(self) -> dict[str, Any]:
        return {"path": str(self.path), "format": self.format, "ok": self.ok, "read": self.read,
                "skipped": self.skipped, "problems": self.problems}

    def lines(self) -> list[str]:
        head = f"{'ok  ' if self.ok else 'FAIL'}  {display_path(self.path)} ({self.format})"
        return ([head] + [f"      read: {line}" for line in self.read]
                + [f"      skipped: {line}" for line in self.skipped]
                + [f"      cannot be evaluated: {line}" for line in self.problems])


def _entry(item: Any) -> str:
    """One skipped thing in words: text as it is; (what, why) as "what: why"; a mapping or an object
    with what / id and why / reason fields likewise."""
    if isinstance(item, str):
        return item
    if callable(getattr(item, "render", None)):  # CommonRoad's ReadNote
        return item.render()
    if type(item).__str__ not in (object.__str__, tuple.__str__, dict.__str__):  # ScenarioNet's Skipped
        return str(item)
    if isinstance(item, (tuple, list)) and len(item) == 2:
        return f"{item[0]}: {item[1]}"
    get = item.get if isinstance(item, dict) else lambda key, default=None: getattr(item, key, default)
    what = next((get(k) for k in ("what", "feature", "id", "name") if get(k) is not None), None)
    why = next((get(k) for k in ("why", "reason") if get(k) is not None), None)
    if what is not None and why is not None:
        return f"{what}: {why}"
    return str(item)


def reader_notes(obj: Any) -> tuple[list[str], list[str]]:
    """What a reader's ``notes`` say, as (read, skipped) lines: CommonRoad's ``ReadNote`` records by
    their action (a value the file left to the reader, "assumed", is a way of reading it), and
    ScenarioNet's sentences (timestamps treated as 0.1 s, a placeholder speed limit) as read."""
    read: list[str] = []
    skipped: list[str] = []
    for note in getattr(obj, "notes", None) or ():
        action, line = getattr(note, "action", ""), _entry(note)
        if action in ("read", "skipped") and line.startswith(action + " "):
            line = line[len(action) + 1:]  # the line's label says it already
        (skipped if action == "skipped" else read).append(line)
    return read, skipped


def skipped_entries(*objects: Any) -> list[str]:
    """What the readers' objects say they left out, in words: each object's ``skipped`` (a list of
    text, of (what, why) pairs, or of records with what / id and why / reason), none when absent."""
    out: list[str] = []
    for obj in objects:
        for name in SKIPPED_ATTRIBUTES:
            listed = getattr(obj, name, None)
            if listed is None or isinstance(listed, (str, bytes)) or not isinstance(listed, Iterable):
                continue
            out.extend(_entry(item) for item in listed)
    return out


def counted(counts: dict[str, int], noun: str = "") -> str:
    """"3 VEHICLE, 1 PEDESTRIAN" (the largest first), or "none"."""
    parts = [f"{n} {kind}" for kind, n in sorted(counts.items(), key=lambda kv: (-kv[1], kv[0]))]
    return ", ".join(parts) + (f" {noun}" if noun and parts else "") if parts else "none"


def plural(n: int, noun: str, many: str | None = None) -> str:
    """"1 scene", "2 scenes"; ``many``: the plural when it is not the noun + "s"."""
    return f"{n} {noun}" if n == 1 else f"{n} {many or noun + 's'}"
