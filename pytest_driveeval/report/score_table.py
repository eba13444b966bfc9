"""nuPlan's score per scene, term by term, as the reports show it: one row per scene with its score
and each term's value (with the first frame where it failed), "n/a" where the scene could not compute
it, and the reasons below.  Read from an item's ``details["scenes"][i]["score_terms"]``."""
from __future__ import annotations

from html import escape
from typing import Any

#: the columns, in the score's order, by nuPlan's metric name
COLUMNS = (("no_ego_at_fault_collisions", "collisions"), ("drivable_area_compliance", "drivable area"),
           ("ego_is_making_progress", "making progress"), ("driving_direction_compliance", "direction"),
           ("ego_progress_along_expert_route", "progress"), ("time_to_collision_within_bound", "TTC"),
           ("speed_limit_compliance", "speed limit"), ("ego_is_comfortable", "comfort"))


def scored_scenes(details: dict[str, Any]) -> list[dict[str, Any]]:
    return [s for s in details.get("scenes") or [] if s.get("score_terms")]


def _cell(term: dict[str, Any]) -> str:
    if term.get("value") is None:
        return "n/a"
    text = f"{term['value']:.3g}"
    return text + (f" (frame {term['frames'][0]})" if term.get("frames") and term["value"] < 1 else "")


def score_rows(details: dict[str, Any]) -> tuple[list[str], list[list[str]], list[str]]:
    """(header, one row per scored scene, notes: why a term was not available, once per reason)."""
    header = ["scene", "score", *(label for _, label in COLUMNS)]
    rows, notes = [], []
    for scene in scored_scenes(details):
        terms = scene["score_terms"]
        # the index (what Scenes: and baselines key on), then which scene in the data it is
        shown = f"{scene['scene']} ({scene['name']})" if scene.get("name") else str(scene["scene"])
        rows.append([shown, f"{scene.get('score', float('nan')):.3f}",
                     *(_cell(terms.get(name, {})) for name, _ in COLUMNS)])
        for name, label in COLUMNS:
            reason = terms.get(name, {}).get("reason")
            note = f"{label}: {reason}"
            if reason and note not in notes:
                notes.append(note)
    return header, rows, notes


def score_markdown(nodeid: str, details: dict[str, Any]) -> list[str]:
    header, rows, notes = score_rows(details)
    if not rows:
        return []
    lines = ["", f"#### nuPlan score per scene: `{nodeid}`", "", "| " + " | ".join(header) + " |",
             "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return lines + ([""] + [f"- {note}" for note in notes] if notes else [])


def score_html(details: dict[str, Any]) -> str:
    header, rows, notes = score_rows(details)
    if not rows:
        return ""
    head = "".join(f"<th>{escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{escape(c)}</td>" for c in row) + "</tr>" for row in rows)
    foot = "".join(f"<li>{escape(n)}</li>" for n in notes)
    return (f"<div class='driveeval-score'><h4>nuPlan score per scene</h4><table><tr>{head}</tr>{body}</table>"
            + (f"<ul>{foot}</ul>" if foot else "") + "</div>")


def score_text(details: dict[str, Any]) -> str:
    """Plain text, for allure's attachment."""
    header, rows, notes = score_rows(details)
    if not rows:
        return ""
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(row, widths)).rstrip() for row in [header, *rows]]
    return "\n".join(lines + notes)
