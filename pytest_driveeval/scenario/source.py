"""Safe YAML loading that remembers where every key and item came from.

Validation errors speak in key paths (``Evaluation.Conditions.PassRate``); people
fix files by line.  ``SourceMap`` connects the two.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from ..core.errors import Problem, ScenarioError


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


# A scenario is a page of YAML.  These bounds let a hostile or broken file
# (an alias "billion laughs", 20,000 nested brackets) fail alone and fast,
# before anything walks the values it would expand to.
MAX_FILE_BYTES = 4 * 1024 * 1024
MAX_EXPANDED_VALUES = 100_000
MAX_DEPTH = 64


def _children(node: yaml.Node) -> list[yaml.Node]:
    if isinstance(node, yaml.MappingNode):
        return [child for pair in node.value for child in pair]
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    return []


def _check_expansion(root: yaml.Node) -> Problem | None:
    """How many values and how deep the document is once aliases are expanded,
    computed on the node graph (an alias is the anchored node itself), so the
    cost is the file's size, not the expansion's."""
    size: dict[int, int] = {}
    depth: dict[int, int] = {}
    on_path: set[int] = set()
    stack: list[tuple[yaml.Node, bool]] = [(root, False)]
    while stack:
        node, children_done = stack.pop()
        key = id(node)
        if children_done:
            on_path.discard(key)
            kids = _children(node)
            size[key] = 1 + sum(size[id(k)] for k in kids)
            depth[key] = 1 + max((depth[id(k)] for k in kids), default=0)
            line = node.start_mark.line + 1
            if size[key] > MAX_EXPANDED_VALUES:
                return Problem(f"this value expands to {size[key]:,} values through anchors and aliases "
                               f"(& and *); a scenario may hold at most {MAX_EXPANDED_VALUES:,}", line)
            if depth[key] > MAX_DEPTH:
                return Problem(f"from here down, values are nested more than {MAX_DEPTH} levels deep; "
                               "a scenario is far flatter", line)
            continue
        if key in size:
            continue
        if key in on_path:
            return Problem("an alias refers to a value that contains it (a recursive anchor)",
                           node.start_mark.line + 1)
        on_path.add(key)
        stack.append((node, True))
        stack.extend((child, False) for child in _children(node) if id(child) not in size)
    return None


def _record_lines(root: yaml.Node, lines: dict[tuple, int]) -> None:
    """Line of every key and item, by key path.  A node reached again through
    an alias is not walked again: its lines are where it is written."""
    seen: set[int] = set()
    stack: list[tuple[yaml.Node, tuple]] = [(root, ())]
    while stack:
        node, keypath = stack.pop()
        lines.setdefault(keypath, node.start_mark.line + 1)
        if id(node) in seen:
            continue
        seen.add(id(node))
        if isinstance(node, yaml.MappingNode):
            for key_node, value_node in node.value:
                if not isinstance(key_node, yaml.ScalarNode):
                    continue
                # A key's line is where the key is written, not where its value starts.
                child = keypath + (key_node.value,)
                lines[child] = key_node.start_mark.line + 1
                stack.append((value_node, child))
        elif isinstance(node, yaml.SequenceNode):
            for index, item in enumerate(node.value):
                child = keypath + (index,)
                lines[child] = item.start_mark.line + 1
                stack.append((item, child))


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
        with open(path, "rb") as handle:
            raw = handle.read(MAX_FILE_BYTES + 1)
        if len(raw) > MAX_FILE_BYTES:
            raise ScenarioError(path, [Problem(
                f"the file is larger than {MAX_FILE_BYTES // 1024 // 1024} MiB; a scenario file is a page of YAML")])
        text = raw.decode("utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ScenarioError(path, [Problem(f"cannot read the file: {exc}")]) from None
    loader = _UniqueKeyLoader(text)
    try:
        node = loader.get_single_node()
        problem = _check_expansion(node) if node is not None else None
        if problem is not None:
            raise ScenarioError(path, [problem])
        data = loader.construct_document(node) if node is not None else None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        line = mark.line + 1 if mark else None
        what = " ".join(part for part in (exc.context, exc.problem) if part)
        raise ScenarioError(path, [Problem(f"YAML syntax error: {what}", line=line)]) from None
    except yaml.YAMLError as exc:
        raise ScenarioError(path, [Problem(f"YAML error: {exc}")]) from None
    except RecursionError:
        # PyYAML composes nested collections recursively.
        raise ScenarioError(path, [Problem(
            f"values nested too deeply to read; a scenario is nested at most {MAX_DEPTH} levels", line=1)]) from None
    finally:
        loader.dispose()
    source = SourceMap(path)
    if node is not None:
        _record_lines(node, source.lines)
    return data, source
