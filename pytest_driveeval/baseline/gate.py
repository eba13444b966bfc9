"""The session's side of baselines: which reference each item meets, the gate that fails an item
that got worse, and the update / prune of a baseline folder at the session's end.

Items are compared where they run (an xdist worker reads the same folder or summary); baselines
are written by the controller only, from the records it gathered, each file atomically.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from ..core.errors import DriveEvalError, display_path
from ..core.outcome import OUTCOME_ATTR, Outcome
from .compare import ERROR, MISSING, STALE, Comparison, against_text, compare
from .payload import make_payload
from .store import BaselineError, BaselineStore, RunReference, relative_path

#: attribute of an item: its comparable record (payload.make_payload), set where its outcome is kept
PAYLOAD_ATTR = "driveeval_payload"
#: attribute of an item: its Comparison
COMPARISON_ATTR = "driveeval_comparison"
NO_BASELINE = "no baseline yet: run with --driveeval-baseline-update"


class RegressionFailed(DriveEvalError, AssertionError):
    """An item that got worse than its reference (an AssertionError: a failed check, not broken input)."""

    def __init__(self, comparison: Comparison, outcome: Outcome | None = None):
        self.comparison = comparison
        self.outcome = outcome
        own = f"\n  its own verdict: {outcome.verdict}: {outcome.summary}" if outcome is not None else ""
        super().__init__(comparison.message() + own)


class BaselineRequired(RegressionFailed):
    """Under --driveeval-baseline-strict: an item without a current baseline (missing or stale);
    nothing got worse, but nothing was compared either."""


@dataclass
class BaselineOptions:
    folder: Path | None = None
    compare_with: Path | None = None  # a summary.json
    update: bool = False
    prune: bool = False
    strict: bool = False
    #: why pytest's rootdir (and so every node id) is not where the test paths put it (session.rootdir_moved)
    rootdir_moved: str | None = None

    @property
    def active(self) -> bool:
        return self.folder is not None or self.compare_with is not None


class Gate:
    """One per process: reads references, compares."""

    def __init__(self, options: BaselineOptions):
        self.options = options
        self.store = BaselineStore(options.folder) if options.folder is not None else None
        self._run: RunReference | None = None

    def reference(self, nodeid: str) -> tuple[dict[str, Any] | None, str, str]:
        """(the item's reference or None, how messages name it, its file)."""
        if self.options.compare_with is not None:
            if self._run is None:
                self._run = RunReference(self.options.compare_with)
            found = self._run.read(nodeid)
            return found, against_text({"run": self._run.run}, "run"), display_path(self.options.compare_with)
        assert self.store is not None
        path = self.store.path_for(nodeid)
        found = self.store.read(nodeid)
        return found, against_text(found or {}), display_path(path)

    def compare(self, nodeid: str, payload: dict[str, Any]) -> Comparison:
        try:
            found, against, source = self.reference(nodeid)
        except BaselineError as exc:
            return Comparison(ERROR, source=nodeid, note=str(exc))
        if found is None:
            note = NO_BASELINE if self.options.compare_with is None else \
                f"{against} has no record of this item (it did not run then)"
            if self.options.rootdir_moved:
                note += f"; but perhaps it has one under another node id: {self.options.rootdir_moved}"
            return Comparison(MISSING, against, source, note=note)
        return compare(found, payload, against, source)

    def must_fail(self, comparison: Comparison) -> bool:
        """Whether the item fails on this comparison (an update accepts what it finds)."""
        if self.options.update:
            return False
        if comparison.status == ERROR or comparison.regressed:
            return True
        return self.options.strict and comparison.status in (MISSING, STALE)


def payload_of(item: Any, outcome: Outcome) -> dict[str, Any]:
    """The item's comparable record: the one the harness made with its scenario, else one from
    the outcome alone (an outcome a Python test made itself: no fingerprint)."""
    made = getattr(item, PAYLOAD_ATTR, None)
    if made is not None and getattr(item, OUTCOME_ATTR, None) is outcome:
        return made
    from ..core.usecase import get_usecase

    return make_payload(outcome, item.nodeid, use_case=get_usecase(outcome.use_case), item=item.name)


def check_item(gate: Gate | None, item: Any, outcome: Outcome) -> Comparison | None:
    """Compare the item's outcome with its reference, keep the comparison on the item for the
    reports, and raise when the item must fail on it."""
    if gate is None or not gate.options.active:
        return None
    comparison = gate.compare(item.nodeid, payload_of(item, outcome))
    setattr(item, COMPARISON_ATTR, comparison)
    if gate.must_fail(comparison):
        if comparison.status == ERROR:
            error = BaselineError(comparison.note)
            error.outcome = outcome
            raise error
        if comparison.regressed:
            raise RegressionFailed(comparison, outcome)
        raise BaselineRequired(comparison, outcome)
    return comparison


def assert_no_regression(outcome: Outcome, baseline: Any) -> Comparison:
    """``outcome`` is not worse than ``baseline``: the ``driveeval_baseline`` fixture (the session's
    reference for this test), or a reference itself (a baseline file's content, or an earlier
    outcome).  Returns the comparison; a missing reference passes (with the fixture, it fails under
    --driveeval-baseline-strict)."""
    __tracebackhide__ = True
    if hasattr(baseline, "gate"):
        comparison = baseline.gate(outcome)
        return comparison if comparison is not None else Comparison(MISSING, note="no baseline option given")
    if isinstance(baseline, Outcome):
        from ..core.usecase import get_usecase

        baseline = make_payload(baseline, "", use_case=get_usecase(baseline.use_case))
    if not isinstance(baseline, dict):
        raise TypeError(f"assert_no_regression: baseline is a {type(baseline).__name__}; give the "
                        "driveeval_baseline fixture, a baseline's content (dict) or an earlier Outcome")
    from ..core.usecase import get_usecase

    current = make_payload(outcome, "", use_case=get_usecase(outcome.use_case))
    if not baseline.get("rules"):
        baseline = {**baseline, "fingerprint": None}
    comparison = compare({**baseline, "fingerprint": None}, {**current, "fingerprint": None},
                         against_text(baseline))
    if comparison.regressed:
        raise RegressionFailed(comparison, outcome)
    return comparison


class ItemBaseline:
    """What the ``driveeval_baseline`` fixture gives a test: its item's reference and the gate.

    ``check(outcome)`` compares and returns the comparison; ``gate(outcome)`` also fails the test
    when the session's rules say so (a regression; a missing or stale baseline under strict).
    """

    def __init__(self, gate: Gate | None, item: Any):
        self._gate = gate
        self._item = item

    @property
    def active(self) -> bool:
        return self._gate is not None

    @property
    def reference(self) -> dict | None:
        return self._gate.reference(self._item.nodeid)[0] if self._gate is not None else None

    def check(self, outcome: Outcome) -> Comparison | None:
        """The comparison of ``outcome`` with the reference (kept for the reports); never raises."""
        if self._gate is None:
            return None
        comparison = self._gate.compare(self._item.nodeid, payload_of(self._item, outcome))
        setattr(self._item, COMPARISON_ATTR, comparison)
        return comparison

    def gate(self, outcome: Outcome) -> Comparison | None:
        __tracebackhide__ = True
        return check_item(self._gate, self._item, outcome)


@dataclass
class Updated:
    """What an update did: files written, files left as they were (nothing but the run would have
    changed), and what went wrong."""
    written: int = 0
    kept: int = 0
    problems: list[str] = field(default_factory=list)

    def line(self, folder: Path) -> str:
        kept = f" ({self.kept} unchanged but for the run, left as they were)" if self.kept else ""
        return f"driveeval baselines: wrote {self.written} in {display_path(folder)}{kept}"


def update_baselines(folder: Path, records: list[dict[str, Any]], run: dict[str, Any]) -> Updated:
    """Write the baselines of the items that ran to the end (controller only); an item that errored
    keeps its old baseline, and so does one whose file would change in nothing but the run."""
    store, done = BaselineStore(folder), Updated()
    problems = done.problems
    for record in records:
        payload = record.get("baseline")
        if not isinstance(payload, dict) or record.get("status") in ("error", "skipped", None):
            continue
        settings = (payload.get("fingerprint") or {}).get("settings") or {}
        if (settings.get("session search") or {}).get("replay"):
            problems.append(f"{record['nodeid']} replayed one case (--driveeval-replay): its baseline, a "
                            "search's result, is kept as it was")
            continue
        try:
            if store.unchanged(record["nodeid"], payload):
                done.kept += 1
                continue
            store.write(record["nodeid"], payload, run)
            done.written += 1
        except (OSError, BaselineError) as exc:
            problems.append(f"cannot write the baseline of {record['nodeid']}: {exc}")
    return done


def unused_baselines(folder: Path, rootdir: Path, items_of: Callable[[Path], set[str] | None]) -> list[Path]:
    """Baseline files of items that no longer exist: their file is gone, or it is a scenario file
    whose items (``items_of``, None: unknown, keep) no longer include theirs.  What this session
    selected does not matter: -k, -m or one node id on the command line prunes nothing."""
    store = BaselineStore(folder)
    out, known = [], {}
    for path, nodeid in store.files().items():
        if nodeid is None or path != store.path_for(nodeid):
            continue  # not a file this plugin wrote there
        file, _, item = nodeid.partition("::")
        where = rootdir / file
        if not where.exists():
            out.append(path)
            continue
        if where not in known:
            known[where] = items_of(where)
        if known[where] is not None and item not in known[where]:
            out.append(path)
    return out


def prune(paths: list[Path], folder: Path) -> list[str]:
    """Delete the unused baseline files (only files whose content says they are ours) and the
    folders they leave empty."""
    problems = []
    for path in paths:
        try:
            path.unlink()
        except OSError as exc:
            problems.append(f"cannot remove {display_path(path)}: {exc}")
            continue
        parent = path.parent
        while parent != folder and parent.is_relative_to(folder):
            try:
                parent.rmdir()
            except OSError:
                break
            parent = parent.parent
    return problems


__all__ = ["BaselineError", "BaselineOptions", "BaselineRequired", "Gate", "ItemBaseline", "RegressionFailed",
           "check_item", "prune", "relative_path", "unused_baselines", "update_baselines"]
