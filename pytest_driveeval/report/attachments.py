"""An outcome's figures and artefacts, handed to the reports people already use.

pytest-html, allure and JUnit XML are each optional: nothing here is imported
or attempted unless that plugin is active and its report was asked for.
Attachments are made on the process that ran the item (an xdist worker too),
once, in the phase that produced the outcome.
"""
from __future__ import annotations

import base64
from pathlib import Path
from typing import Any

import pytest

from ..core.outcome import Outcome, format_figure, plain, replaced_model
from .deltas import comparison_of, figure_deltas, status_text, status_tone
from .score_table import score_html, score_text

IMAGE_TYPES = {".png": "image/png", ".gif": "image/gif", ".jpg": "image/jpeg", ".svg": "image/svg+xml"}
TREND_NAME = "trend"
TEXT_TYPES = {".json": "json", ".jsonl": "text", ".txt": "text", ".csv": "text", ".md": "text"}


def html_wanted(config: pytest.Config) -> bool:
    return config.pluginmanager.hasplugin("html") and bool(config.getoption("htmlpath", None))


def allure_wanted(config: pytest.Config) -> bool:
    return config.pluginmanager.hasplugin("allure_pytest") and bool(config.getoption("allure_report_dir", None))


def scalar_figures(outcome: Outcome) -> dict[str, Any]:
    """The figures that are one value, as plain Python (a numpy scalar's type is no reader's business)."""
    figures = {k: plain(v) for k, v in outcome.figures.items()}
    return {k: v for k, v in figures.items() if isinstance(v, (bool, int, float, str))}


def case_parameter(case_name: str) -> str:
    """What the brackets of an item's name hold (the dataset, the policy, a policy and problem), or ""."""
    return case_name[case_name.index("[") + 1:-1] if case_name.endswith("]") and "[" in case_name else ""


def junit_properties(outcome: Outcome) -> list[tuple[str, str]]:
    """Key figures as JUnit test-case properties (``driveeval.<figure>``)."""
    props = [("driveeval.use_case", outcome.use_case), ("driveeval.verdict", outcome.verdict)]
    return props + [(f"driveeval.{k}", format_figure(v)) for k, v in scalar_figures(outcome).items()]


#: inline, so a self-contained report and any reader of the extras see them (pytest-html has no such class)
TONE_STYLE = {"worse": "color:#c62828;font-weight:bold", "better": "color:#2e7d32;font-weight:bold",
              "note": "color:#ef6c00"}


def _figures_table(outcome: Outcome, record: dict[str, Any] | None = None) -> str:
    """The figures; with a comparison, each key figure also with its reference's value and the change."""
    from html import escape

    deltas = {d.name: d for d in figure_deltas(record or {})}
    rows = []
    for k, v in scalar_figures(outcome).items():
        cells = f"<td>{escape(k)}</td><td>{escape(format_figure(v))}</td>"
        delta = deltas.get(k)
        if delta is not None:
            before = "" if delta.before is None else format_figure(delta.before)
            style = TONE_STYLE.get(delta.tone or "", "")
            cells += (f"<td class='driveeval-baseline-value'>{escape(before)}</td>"
                      f"<td class='driveeval-change driveeval-{delta.tone or 'same'}' style='{style}'>"
                      f"{escape(delta.change)}</td>")
        elif deltas:
            cells += "<td></td><td></td>"
        rows.append(f"<tr>{cells}</tr>")
    head = "<tr><th>figure</th><th>now</th><th>baseline</th><th>change</th></tr>" if deltas else ""
    model = replaced_model(outcome.details)
    model = f"<p class='driveeval-model'>{escape(model)}</p>" if model else ""
    return (f"<div class='driveeval'><p><b>{escape(outcome.use_case)}: {escape(outcome.verdict)}</b> "
            f"{escape(outcome.summary)}</p>{model}{_comparison_html(record or {})}<table>{head}{''.join(rows)}"
            f"</table></div>")


def comparison_cell(record: dict[str, Any] | None) -> str:
    """pytest-html's results table: the item's comparison in a cell (its status and the figures
    that moved beyond their tolerance), empty for an item not compared."""
    from html import escape

    comparison = comparison_of(record or {})
    if comparison is None:
        return '<td class="col-driveeval-baseline"></td>'
    moved = ", ".join(f"<span style='{TONE_STYLE[d.tone]}'>{escape(d.name)} {escape(d.change)}</span>"
                      for d in figure_deltas(record or {}) if d.tone)
    style = TONE_STYLE.get(status_tone(record or {}) or "", "")
    return (f'<td class="col-driveeval-baseline"><span style="{style}">{escape(comparison["status"])}</span>'
            f'{": " + moved if moved else ""}</td>')


def _comparison_html(record: dict[str, Any]) -> str:
    from html import escape

    comparison = comparison_of(record)
    if comparison is None:
        return ""
    lines = (comparison.get("message") or "").splitlines()
    style = TONE_STYLE.get(status_tone(record) or "", "")
    rest = "".join(f"<br>{escape(line.strip())}" for line in lines[1:])
    return (f"<p class='driveeval-comparison driveeval-{escape(comparison['status'])}'><span style='{style}'>"
            f"{escape(status_text(record))}</span>: {escape(lines[0] if lines else '')}{rest}</p>")


def search_lines(outcome: Outcome) -> list[str]:
    """A robustness search in a few lines: what broke it, where, the statistics, the replay.
    Reports show them also when the item is an expected failure, whose pytest
    report keeps nothing but the reason."""
    search = outcome.details.get("search")
    if not search:
        return []
    lines = [f"robustness search ({search.get('profile')} profile): {search.get('examples')} examples, "
             f"{search.get('failures')} failing, {search.get('generations')} generation(s) of "
             f"{search.get('batch')}, {search.get('seconds')} s; replayed first from the example database: "
             f"{search.get('replayed_from_database')}"]
    if search.get("minimal_text"):
        where = ", ".join(f"{k} {v}" for k, v in (search.get("where") or {}).items())
        lines += [f"smallest failing perturbation: {search['minimal_text']} (shrunk by hypothesis to "
                  f"{search.get('shrunk_text')}, then moved to the edge of failure)",
                  f"where: {where}: {search.get('reason')}", f"replay: {search.get('replay')}"]
    return lines


def executor_lines(outcome: Outcome) -> list[str]:
    """Where an item's chunks ran, when it ran them on an executor (a Ray cluster): the summary,
    then a line per chunk (host, node, pid, attempts, seconds)."""
    where = outcome.details.get("executor")
    if not where:
        return []
    lines = [f"executor: {where.get('summary')}"]
    for chunk in where.get("chunks") or []:
        node = f" node {chunk['node'][:8]}" if chunk.get("node") not in (None, "local") else ""
        retried = f", {chunk['attempts']} attempts" if chunk.get("attempts", 1) > 1 else ""
        lines.append(f"chunk {chunk['chunk']} ({chunk.get('work')}): {chunk.get('host')}{node} pid "
                     f"{chunk.get('pid')}{retried}, {chunk.get('seconds')} s")
    return lines


def html_extras(outcome: Outcome, record: dict[str, Any] | None = None, trend: bytes | None = None) -> list[dict]:
    """pytest-html extras: a figures table (with the item's baseline when ``record`` has a
    comparison), the key figures' trend over the last runs, images inline (base64, so a
    self-contained report carries them), result files as JSON / text."""
    from html import escape

    from pytest_html import extras

    out = [extras.html(_figures_table(outcome, record))]
    scores = score_html(outcome.details)
    if scores:
        out.append(extras.html(scores))
    lines = search_lines(outcome)
    if lines:
        out.append(extras.html("<div class='driveeval-search'>" + "".join(f"<p>{escape(line)}</p>" for line in lines)
                               + "</div>"))
    lines = executor_lines(outcome)
    if lines:
        out.append(extras.html("<details class='driveeval-executor'><summary>" + escape(lines[0]) + "</summary>"
                               + "".join(f"<p>{escape(line)}</p>" for line in lines[1:]) + "</details>"))
    # pytest-html shows images one at a time: animations first, they say the most.
    ordered = sorted(outcome.artefacts.items(), key=lambda item: Path(item[1]).suffix.lower() != ".gif")
    for name, path in ordered:
        path = Path(path)
        suffix = path.suffix.lower()
        if not path.is_file():
            continue
        if suffix in IMAGE_TYPES:
            data = base64.b64encode(path.read_bytes()).decode("ascii")
            out.append(extras.image(data, name=name, mime_type=IMAGE_TYPES[suffix], extension=suffix[1:]))
        elif suffix in TEXT_TYPES:
            text = path.read_text(encoding="utf-8")
            out.append(extras.json(text, name=name) if TEXT_TYPES[suffix] == "json" else extras.text(text, name=name))
    if trend:
        out.append(extras.image(base64.b64encode(trend).decode("ascii"), name=TREND_NAME, mime_type="image/png",
                                extension="png"))
    return out


def attach_to_allure(outcome: Outcome, scenario: Any = None, dataset: str | None = None,
                     trend: bytes | None = None, case: Any = None) -> None:
    """Allure: scenario and use case as labels, figures as parameters, artefacts
    as typed attachments, the key figures' trend over the last runs.  Called while
    the test runs, so allure files them under it.  (Allure's own trend widgets count
    statuses and durations per report, from a history/ folder its report generator
    makes: no figure of ours can go there, so the figures' trend is a plot.)"""
    import allure
    from allure_commons.types import AttachmentType

    types = {".png": AttachmentType.PNG, ".gif": AttachmentType.GIF, ".json": AttachmentType.JSON,
             ".jsonl": AttachmentType.TEXT, ".txt": AttachmentType.TEXT, ".csv": AttachmentType.CSV,
             ".jpg": AttachmentType.JPG, ".svg": AttachmentType.SVG}
    allure.dynamic.label("use_case", outcome.use_case)
    allure.dynamic.feature(outcome.use_case)
    # The title carries what the item's id has in brackets: the five policies of one benchmark
    # (no dataset) were five results of one name.
    shown = case_parameter(case.name) if case is not None else dataset
    if scenario is not None:
        allure.dynamic.title(f"{scenario.name}" + (f" [{shown}]" if shown else ""))
        allure.dynamic.story(scenario.name)
        if scenario.description:
            allure.dynamic.description(scenario.description)
    if dataset:
        allure.dynamic.parameter("dataset", dataset)
    for key, value in (case.params if case is not None else {}).items():
        # Part of allure's history id, as the dataset is: each policy is a test of its own.
        allure.dynamic.parameter(key, plain(value))
    if outcome.details.get("model"):
        # Part of allure's history id: another model's result is not this test's trend.
        allure.dynamic.parameter("model", outcome.details["model"])
    for key, value in scalar_figures(outcome).items():
        # Excluded from allure's history id: a figure changing is the news, not a new test.
        allure.dynamic.parameter(key, value, excluded=True)
    scores = score_text(outcome.details)
    if scores:
        allure.attach(scores, name="nuPlan score per scene", attachment_type=AttachmentType.TEXT)
    lines = search_lines(outcome)
    if lines:
        allure.attach("\n".join(lines), name="robustness search", attachment_type=AttachmentType.TEXT)
    lines = executor_lines(outcome)
    if lines:
        allure.attach("\n".join(lines), name="where the chunks ran", attachment_type=AttachmentType.TEXT)
    if trend:
        allure.attach(trend, name=TREND_NAME, attachment_type=AttachmentType.PNG)
    for name, path in outcome.artefacts.items():
        path = Path(path)
        if path.is_file():
            allure.attach.file(str(path), name=name, attachment_type=types.get(path.suffix.lower()),
                               extension=None if path.suffix.lower() in types else path.suffix[1:])
