"""The paired comparisons a policy benchmark item reports (its ``Compare`` list and its ``Beats``):
one line per (policy, other policy) with the probability that the policy does better on an
episode and the difference of rates, each with its interval.  seed 002's question "GNN-SAC vs
SAC, random and constant" is answered by these lines, whichever way the numbers go."""
from __future__ import annotations

import re
from typing import Any

__all__ = ["paired_rows", "paired_table"]

_KEY = re.compile(r"^(?:vs|beats)_(?P<other>.+)_(?P<metric>goal_rate|collision_rate|return)$")
_LABEL = {"goal_rate": "goal", "collision_rate": "no collision", "return": "return"}


def _interval(v: dict[str, Any], scale: float, digits: int) -> str:
    return f"{scale * v['point']:.{digits}f} [{scale * v['low']:.{digits}f}, {scale * v['high']:.{digits}f}]"


def paired_rows(records: list[dict[str, Any]]) -> list[tuple[str, str, str, str, str, str]]:
    """(scenario or blueprint, policy, other, measure, P(better) with interval, difference with interval)."""
    rows = []
    for r in records:
        details = r.get("details") or {}
        policy, intervals = details.get("policy"), details.get("intervals") or {}
        for key, value in intervals.items():
            match = _KEY.match(key)
            if policy is None or match is None or not isinstance(value, dict) or "improvement" not in value:
                continue
            metric = match["metric"]
            # A rate's difference is in percentage points already; a return's in its own units.
            difference = _interval(value["difference"], 1.0, 1 if metric != "return" else 2)
            rows.append((str(r.get("scenario") or details.get("blueprint") or ""), str(policy), match["other"],
                         _LABEL[metric], _interval(value["improvement"], 1.0, 2), difference))
    return sorted(set(rows))


def paired_table(records: list[dict[str, Any]]) -> list[str]:
    """The paired comparisons as Markdown (nothing when no item made one)."""
    rows = paired_rows(records)
    if not rows:
        return []
    lines = ["", "### Paired comparisons (the same seeded episodes)", "",
             "| scenario | policy | against | on | P(policy better) | difference (policy - other) |",
             "|---|---|---|---|---|---|"]
    lines += ["| " + " | ".join(cell.replace("|", "\\|") for cell in row) + " |" for row in rows]
    return lines
