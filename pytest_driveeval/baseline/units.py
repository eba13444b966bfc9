"""Per-unit outcomes (scenes, frames, episodes) in a compact, diff-friendly form.

A baseline keeps, besides an item's figures, how each of its units ended, so that a comparison can
name the scene, frame or episode that changed, and a paired test can count the discordant ones.
One character per unit and column, in unit order, cut into lines of :data:`LINE` characters: a
change of one unit changes one line of the file.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

LINE = 64


@dataclass
class Units:
    kind: str  # "scene", "frame", "episode": how a message names one
    ids: list[str]
    #: column -> one code per unit
    columns: dict[str, str]
    #: code -> word, for messages ("g" -> "goal")
    legend: dict[str, str]
    #: column -> the codes that count as a good end of a unit
    good: dict[str, str]
    #: unit id -> why it ended badly (a condition and its frame), where the evaluation says
    reasons: dict[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name, codes in self.columns.items():
            if len(codes) != len(self.ids):
                raise ValueError(f"units.columns.{name}: {len(codes)} code(s) for {len(self.ids)} {self.kind}(s)")
            unknown = sorted(set(codes) - set(self.legend))
            if unknown:
                raise ValueError(f"units.columns.{name}: code(s) {', '.join(map(repr, unknown))} not in the legend")

    def word(self, code: str) -> str:
        return self.legend.get(code, code)

    def is_good(self, column: str, index: int) -> bool:
        return self.columns[column][index] in self.good.get(column, "")

    def to_json(self) -> dict[str, Any]:
        return {"kind": self.kind, "ids": compact_ids(self.ids),
                "columns": {name: _lines(codes) for name, codes in self.columns.items()},
                "legend": dict(sorted(self.legend.items())), "good": dict(self.good),
                "reasons": dict(self.reasons)}

    @classmethod
    def from_json(cls, data: Any) -> "Units":
        """Read what :meth:`to_json` wrote; a ValueError names the key that is wrong."""
        if not isinstance(data, dict):
            raise ValueError("units: not a mapping")
        kind = _of(data, "kind", str)
        legend = _of(data, "legend", dict)
        good = _of(data, "good", dict)
        reasons = data.get("reasons", {})
        columns = _of(data, "columns", dict)
        if not all(isinstance(v, str) and len(k) == 1 for k, v in legend.items()):
            raise ValueError("units.legend: not a mapping of one-character codes to words")
        if not all(isinstance(v, str) for v in good.values()):
            raise ValueError("units.good: not a mapping of columns to codes")
        if not isinstance(reasons, dict) or not all(isinstance(v, str) for v in reasons.values()):
            raise ValueError("units.reasons: not a mapping of units to text")
        cols = {}
        for name, lines in columns.items():
            if not isinstance(lines, list) or not all(isinstance(line, str) for line in lines):
                raise ValueError(f"units.columns.{name}: not a list of lines of codes")
            cols[name] = "".join(lines)
        ids = data.get("ids")
        count = ids.get("count") if isinstance(ids, dict) else None
        for name, codes in cols.items():
            # Said before the ids are made: a hand-edited count must not allocate millions of them.
            if isinstance(count, int) and len(codes) != count:
                raise ValueError(f"units.columns.{name}: {len(codes)} code(s) for {count} {kind}(s)")
        return cls(kind, expand_ids(ids), cols, legend, good, {str(k): v for k, v in reasons.items()})


def _of(data: dict, key: str, kind: type) -> Any:
    value = data.get(key)
    if not isinstance(value, kind):
        raise ValueError(f"units.{key}: missing or not a {kind.__name__}")
    return value


def _lines(codes: str) -> list[str]:
    return [codes[i:i + LINE] for i in range(0, len(codes), LINE)]


def compact_ids(ids: list[str]) -> Any:
    """Consecutive whole numbers as ``{"from": a, "count": n}``; anything else as the list."""
    # isascii: "²" and "١" are digits to isdigit(), and int() would not give them back
    if ids and all(i.isascii() and i.isdigit() and (i == "0" or not i.startswith("0")) for i in ids):
        first = int(ids[0])
        if [int(i) for i in ids] == list(range(first, first + len(ids))):
            return {"from": first, "count": len(ids)}
    return list(ids)


def expand_ids(data: Any) -> list[str]:
    if isinstance(data, dict) and isinstance(data.get("from"), int) and isinstance(data.get("count"), int) \
            and not isinstance(data["from"], bool) and 0 <= data["count"] <= 10 ** 8:
        return [str(i) for i in range(data["from"], data["from"] + data["count"])]
    if isinstance(data, list) and all(isinstance(i, (str, int)) and not isinstance(i, bool) for i in data):
        return [str(i) for i in data]
    raise ValueError("units.ids: neither {from, count} nor a list of ids")


@dataclass(frozen=True)
class UnitChange:
    unit: str
    column: str
    before: str
    after: str
    worse: bool
    reason: str = ""


def unit_changes(before: Units, after: Units) -> list[UnitChange]:
    """Units present in both whose good / bad end flipped, in unit order."""
    position = {unit: i for i, unit in enumerate(before.ids)}
    out = []
    for j, unit in enumerate(after.ids):
        i = position.get(unit)
        if i is None:
            continue
        for column in after.columns:
            if column not in before.columns:
                continue
            was, now = before.is_good(column, i), after.is_good(column, j)
            if was != now:
                out.append(UnitChange(unit, column, before.word(before.columns[column][i]),
                                      after.word(after.columns[column][j]), worse=was,
                                      reason=(after.reasons if was else before.reasons).get(unit, "")))
    return out
