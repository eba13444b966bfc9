"""The trend reader: each item's key figures from the output folder's history, past what cannot be read."""
from __future__ import annotations

import json

from pytest_driveeval.report.trends import read_history, series, trend_png

PNG = b"\x89PNG\r\n\x1a\n"


def write_run(root, run_id: str, records: list[dict], started: str = "2026-11-20T10:00:00+00:00") -> str:
    folder = root / "runs" / run_id
    folder.mkdir(parents=True)
    (folder / "summary.json").write_text(json.dumps({"results": records}))
    return json.dumps({"run": {"id": run_id, "started": started}, "summary": f"runs/{run_id}/summary.json"})


def item(goal: float, collision: float, nodeid: str = "a.yaml::x") -> dict:
    # The key figures come from the payload ("baseline"), not the outcome's every figure.
    return {"nodeid": nodeid, "figures": {"goal_rate": goal, "collision_rate": collision, "episodes": 32},
            "baseline": {"figures": {"goal_rate": goal, "collision_rate": collision}}}


def history(tmp_path) -> tuple:
    lines = [
        write_run(tmp_path, "r1", [item(100, 0)], "2026-11-20T10:00:00+00:00"),
        "{not json",                                                       # a crash mid-line
        write_run(tmp_path, "r2", [item(90, 5), item(50, 50, "b.yaml::y")], "2026-11-21T10:00:00+00:00"),
        json.dumps({"run": {"id": "gone"}, "summary": "runs/gone/summary.json"}),   # pruned since
        json.dumps({"run": {"id": "out"}, "summary": "/etc/passwd"}),              # not its folder's
        json.dumps(["a", "list"]),
        write_run(tmp_path, "r3", [{"nodeid": "a.yaml::x", "figures": {"goal_rate": 80.0}}],  # an older record
                  "2026-11-22T10:00:00+00:00"),
        write_run(tmp_path, "r4", [item(1, 1, "b.yaml::y")], "2026-11-23T10:00:00+00:00"),  # x did not run
    ]
    (tmp_path / "runs" / "r5").mkdir()
    (tmp_path / "runs" / "r5" / "summary.json").write_text('{"results": [')          # truncated
    lines.append(json.dumps({"run": {"id": "r5"}, "summary": "runs/r5/summary.json"}))
    path = tmp_path / "history.jsonl"
    path.write_text("\n".join(lines) + "\n")
    return path


def test_reader_skips_corrupt_lines_missing_and_foreign_summaries(tmp_path):
    runs = read_history(history(tmp_path))
    assert [r.id for r in runs] == ["r1", "r2", "r3", "r4"]
    assert runs[0].figures == {"a.yaml::x": {"goal_rate": 100.0, "collision_rate": 0.0}}
    assert runs[2].figures == {"a.yaml::x": {"goal_rate": 80.0}}


def test_series_per_item_with_the_current_run_last(tmp_path):
    labels, points = series(read_history(history(tmp_path)), "a.yaml::x", {"goal_rate": 70.0, "collision_rate": 10})
    assert labels == ["11-20 10:00", "11-21 10:00", "11-22 10:00", "this run"]
    assert points == {"goal_rate": [(0, 100.0), (1, 90.0), (2, 80.0), (3, 70.0)],
                      "collision_rate": [(0, 0.0), (1, 5.0), (3, 10.0)]}


def test_only_the_last_runs_and_never_the_current_one_from_the_history(tmp_path):
    path = history(tmp_path)
    assert [r.id for r in read_history(path, limit=2)] == ["r3", "r4"]
    labels, points = series(read_history(path), "b.yaml::y", {"goal_rate": 2.0}, current_id="r4")
    assert labels == ["11-21 10:00", "this run"] and points == {"goal_rate": [(0, 50.0), (1, 2.0)]}


def test_history_read_once_until_it_changes(tmp_path):
    path = history(tmp_path)
    first = read_history(path)
    assert read_history(path) is first
    with path.open("a") as handle:  # a session finished since (pytest.main twice in one process)
        handle.write(write_run(tmp_path, "r6", [item(60, 0)]) + "\n")
    assert [r.id for r in read_history(path)][-1] == "r6"


def test_plot_only_with_an_earlier_run_of_the_item(tmp_path):
    path = history(tmp_path)
    png = trend_png(path, "a.yaml::x", {"goal_rate": 70.0, "collision_rate": 10.0}, "now")
    assert png is not None and png.startswith(PNG) and len(png) > 2000
    assert trend_png(path, "new.yaml::z", {"goal_rate": 70.0}, "now") is None
    assert trend_png(tmp_path / "absent.jsonl", "a.yaml::x", {"goal_rate": 70.0}, "now") is None
