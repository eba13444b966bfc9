"""Turn pydantic validation errors into located, actionable problems."""
from __future__ import annotations

import difflib
import types
import typing
from typing import Any, Sequence

from pydantic import BaseModel, ValidationError

from ..core.errors import Problem
from .source import SourceMap


def did_you_mean(word: str, choices: Sequence[str]) -> str:
    close = difflib.get_close_matches(str(word), [str(c) for c in choices], n=1, cutoff=0.6)
    if close:
        return f"did you mean '{close[0]}'?"
    if choices:
        return "expected one of: " + ", ".join(sorted(map(str, choices)))
    return ""


def _unwrap(annotation: Any) -> Any:
    """Optional[X] / Union[X, ...] -> the model among them, else the first non-None."""
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(annotation) if a is not type(None)]
        for arg in args:
            if isinstance(arg, type) and issubclass(arg, BaseModel):
                return arg
        return args[0] if args else annotation
    if typing.get_origin(annotation) is typing.Annotated:
        return _unwrap(typing.get_args(annotation)[0])
    return annotation


def _model_keys(model: type[BaseModel]) -> list[str]:
    return [f.alias or name for name, f in model.model_fields.items()]


def allowed_keys(model: type[BaseModel], parent: Sequence[Any]) -> list[str]:
    """The keys the model accepts at ``parent`` (a key path into its input)."""
    current: Any = model
    for part in parent:
        current = _unwrap(current)
        if isinstance(current, type) and issubclass(current, BaseModel):
            match = [f for n, f in current.model_fields.items() if (f.alias or n) == part]
            if not match:
                return []
            current = match[0].annotation
        elif typing.get_origin(current) in (list, tuple, typing.Sequence) and isinstance(part, int):
            current = typing.get_args(current)[0]
        elif typing.get_origin(current) in (dict, typing.Mapping):
            current = typing.get_args(current)[1]
        else:
            return []
    current = _unwrap(current)
    if isinstance(current, type) and issubclass(current, BaseModel):
        return _model_keys(current)
    return []


def _data_loc(loc: Sequence[Any], data: Any, keep_last: bool) -> tuple:
    """Drop the parts of pydantic's loc that are not keys of the data (union tags)."""
    out: list[Any] = []
    node = data
    for i, part in enumerate(loc):
        last = i == len(loc) - 1
        if isinstance(node, dict) and part in node:
            out.append(part)
            node = node[part]
        elif isinstance(node, list) and isinstance(part, int) and 0 <= part < len(node):
            out.append(part)
            node = node[part]
        elif last and keep_last:
            out.append(part)
    return tuple(out)


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _describe(error: dict) -> str:
    msg = error["msg"]
    for prefix, replacement in (("Input should be ", "expected "), ("Value error, ", ""), ("Assertion failed, ", "")):
        if msg.startswith(prefix):
            msg = replacement + msg[len(prefix):]
            break
    else:
        msg = msg[:1].lower() + msg[1:]
    if error["type"].endswith("_type") or error["type"].endswith("_parsing") or msg.startswith("expected"):
        value = error.get("input")
        msg += f"; found {_short(value)} ({type(value).__name__})"
    return msg


def problems_from_validation(
    exc: ValidationError,
    model: type[BaseModel],
    data: Any,
    source: SourceMap,
    prefix: tuple = (),
) -> list[Problem]:
    missing: list[tuple] = []
    extra: list[tuple] = []
    others: list[Problem] = []
    for error in exc.errors():
        kind = error["type"]
        loc = _data_loc(error["loc"], data, keep_last=kind in ("missing", "extra_forbidden"))
        if kind == "missing":
            missing.append(loc)
        elif kind == "extra_forbidden":
            extra.append(loc)
        else:
            others.append(Problem(_describe(error), source.line_of(prefix + loc), prefix + loc))

    problems: list[Problem] = []
    suggested: set[tuple] = set()
    for loc in extra:
        parent, key = loc[:-1], loc[-1]
        choices = [k for k in allowed_keys(model, parent) if not isinstance(data, dict) or k != key]
        hint = did_you_mean(key, choices)
        close = difflib.get_close_matches(str(key), choices, n=1, cutoff=0.6)
        if close:
            suggested.add(parent + (close[0],))
        message = f"unknown key '{key}'" + (f"; {hint}" if hint else "")
        problems.append(Problem(message, source.line_of(prefix + loc), prefix + loc))
    for loc in missing:
        # A misspelt required key shows up as unknown + missing; the first says it all.
        if loc in suggested:
            continue
        parent = loc[:-1]
        problems.append(Problem(f"missing required key '{loc[-1]}'", source.line_of(prefix + parent), prefix + parent))
    problems.extend(others)
    return sorted(problems, key=lambda p: (p.line or 0, p.keypath.__repr__()))
