"""Which scene a closed-loop result is about, said so that a user with a folder of their own can
find the file: the scene's index (what ``Scenes:``, ``-k`` and baselines key on, unchanged) and its
identity in the data (ScenarioNet: the scenario id and its file; L5: the zarr).

Every rule writes its findings as ``scene N: ...`` (verdict.within, verdict.violations, the
engine's errors, the score's findings), here or on a worker; :func:`name_verdicts` adds the
scene's name once, on the process that holds the dataset, so each of them carries it and none has
to be taught.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Iterable

from pytest_driveeval.core.errors import DataError
from pytest_driveeval.core.filenames import safe_name_part
from pytest_driveeval.core.outcome import Finding

__all__ = ["caption", "gif_name", "name_findings", "name_verdicts", "named", "scene_identity", "scene_label"]


def scene_identity(dataset: Any, index: int, read: bool = True) -> dict[str, Any]:
    """What names scene ``index`` in its data: ``{"index", "scenario_id", "file"}`` for ScenarioNet
    (``scenario_id`` left out when its file cannot be read, or ``read`` is False: a scene known to be
    broken is not read again), ``{"index", "zarr"}`` for an L5 zarr, ``{"index"}`` alone for a
    dataset object that says nothing about its files."""
    identity: dict[str, Any] = {"index": int(index)}
    files = getattr(dataset, "files", None)
    if files is not None and getattr(dataset, "source", None) is not None:  # io.scenarionet ScenarioNetDataset
        if 0 <= index < len(files):
            identity["file"] = Path(files[index]).name
            if read:
                try:  # read when its scene was: the reader keeps it
                    identity["scenario_id"] = str(dataset.source(index).id)
                except (DataError, OSError, ValueError, TypeError, KeyError, AttributeError):
                    pass  # its finding says why; the file names it
        return identity
    path = getattr(dataset, "path", None)
    if path is not None:
        identity["zarr"] = Path(path).name
    return identity


def scene_label(identity: dict[str, Any]) -> str:
    """The name in words, after "scene N": "scenario <id>, <file>" or "<zarr>" (empty when unknown)."""
    parts = []
    if identity.get("scenario_id"):
        parts.append(f"scenario {identity['scenario_id']}")
    for key in ("file", "zarr"):
        if identity.get(key):
            parts.append(str(identity[key]))
    return ", ".join(parts)


def named(scene: int, identity: dict[str, Any]) -> str:
    """``scene N (label)``, or ``scene N`` when the label is empty."""
    label = scene_label(identity)
    return f"scene {scene} ({label})" if label else f"scene {scene}"


def gif_name(scene: int, identity: dict[str, Any]) -> str:
    """The scene's GIF file name: ``scene_<index>_<scenario id or file stem>.gif``; ``scene_<index>.gif``
    when the dataset says nothing about the scene."""
    what = identity.get("scenario_id") or Path(str(identity.get("file") or identity.get("zarr") or "")).stem
    return f"scene_{scene}_{safe_name_part(str(what))}.gif" if what else f"scene_{scene}.gif"


def caption(scene: int, identity: dict[str, Any]) -> str:
    """The GIF's caption: the index and the shortest part of the name that finds the scene (the
    scenario id, else the file), bounded so that the frame number still fits a 320-px frame."""
    what = str(identity.get("scenario_id") or identity.get("file") or identity.get("zarr") or "")
    if len(what) > 32:
        what = what[:15] + "~" + what[-16:]
    return f"scene {scene} ({what})" if what else f"scene {scene}"


def name_findings(findings: Iterable[Finding], names: dict[int, str]) -> None:
    """Put each finding's scene name after its ``scene N`` (in place; once, a named one is left)."""
    for finding in findings:
        scene = finding.scene
        if not isinstance(scene, int) or scene not in names:
            continue
        bare = f"scene {scene}"
        full = names[scene]
        if full != bare and finding.message.startswith(bare) and not finding.message.startswith(full) \
                and finding.message[len(bare):len(bare) + 1] in (":", " ", ""):
            finding.message = full + finding.message[len(bare):]


def name_verdicts(dataset: Any, verdicts: list, problems: list[Finding]) -> dict[int, dict[str, Any]]:
    """Each verdict's scene identity by index; its findings and ``problems`` (the scenes that could
    not be unrolled) named.  The error text a verdict keeps is named by the caller from the same map."""
    unrolled = {int(v.scene) for v in verdicts}
    unread = {int(f.scene) for f in problems if isinstance(f.scene, int)} - unrolled
    count = getattr(dataset, "num_scenes", None)
    identities = {s: scene_identity(dataset, s, read=s in unrolled) for s in sorted(unrolled | unread)
                  if count is None or 0 <= s < count}
    names = {s: named(s, identity) for s, identity in identities.items()}
    name_findings(problems, names)
    for verdict in verdicts:
        name_findings(verdict.findings, names)
    return identities


def named_text(text: str | None, scene: int, identities: dict[int, dict[str, Any]]) -> str | None:
    """An engine error's text (``scene N: ...``) with the scene's name, as its finding says it."""
    if not text or scene not in identities:
        return text
    finding = Finding(text, scene=scene)
    name_findings([finding], {scene: named(scene, identities[scene])})
    return finding.message
