"""Safe YAML loading that remembers where every key and item came from.

Validation errors speak in key paths (``Evaluation.Conditions.PassRate``); people
fix files by line.  ``SourceMap`` connects the two.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from ..errors import Problem, ScenarioError


@dataclass
class SourceMap:
    path: Path
    lines: dict[tuple, int] = field(default_factory=dict)

    def line_of(self, keypath: tuple | list) -> int | None:
        """Line of the deepest existing node along ``keypath`` (1-based)."""
        keypath = tuple(keypath)
        while True:
            if keypath in self.lines:
                return self.lines[keypath]
            if not keypath:
                return None
            keypath = keypath[:-1]


def _record_lines(node: yaml.Node, keypath: tuple, lines: dict[tuple, int]) -> None:
    lines.setdefault(keypath, node.start_mark.line + 1)
    if isinstance(node, yaml.MappingNode):
        for key_node, value_node in node.value:
            if not isinstance(key_node, yaml.ScalarNode):
                continue
            # A key's line is where the key is written, not where its value starts.
            child = keypath + (key_node.value,)
            lines[child] = key_node.start_mark.line + 1
            _record_lines(value_node, child, lines)
    elif isinstance(node, yaml.SequenceNode):
        for index, item in enumerate(node.value):
            child = keypath + (index,)
            lines[child] = item.start_mark.line + 1
            _record_lines(item, child, lines)


class _UniqueKeyLoader(yaml.SafeLoader):
    """SafeLoader that rejects duplicate keys, which PyYAML silently overwrites."""

    def construct_mapping(self, node, deep=False):
        seen: dict[Any, int] = {}
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=True)
            try:
                first = seen.get(key)
            except TypeError:
                continue
            if first is not None:
                raise yaml.constructor.ConstructorError(
                    None, None,
                    f"duplicate key {key!r} (first defined on line {first})",
                    key_node.start_mark,
                )
            seen[key] = key_node.start_mark.line + 1
        return super().construct_mapping(node, deep=deep)


def load_yaml_with_lines(path: Path) -> tuple[Any, SourceMap]:
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ScenarioError(path, [Problem(f"cannot read the file: {exc}")]) from None
    loader = _UniqueKeyLoader(text)
    try:
        node = loader.get_single_node()
        data = loader.construct_document(node) if node is not None else None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        line = mark.line + 1 if mark else None
        what = " ".join(part for part in (exc.context, exc.problem) if part)
        raise ScenarioError(path, [Problem(f"YAML syntax error: {what}", line=line)]) from None
    except yaml.YAMLError as exc:
        raise ScenarioError(path, [Problem(f"YAML error: {exc}")]) from None
    finally:
        loader.dispose()
    source = SourceMap(path)
    if node is not None:
        _record_lines(node, (), source.lines)
    return data, source
