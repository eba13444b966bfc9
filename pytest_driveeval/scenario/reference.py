"""The manual's page of every scenario key (docs/reference/scenario-keys.md), made from the models
that validate the keys, so that the page cannot say what the code does not.

    python -m pytest_driveeval.scenario.reference            # rewrite docs/reference/scenario-keys.md
    python -m pytest_driveeval.scenario.reference --check    # exit 1 if the committed page differs

Each key's row gives its path in the YAML file, its type, its default and its meaning: the field's
``description``.  A field without one stops the page from being made, naming it, so that a new key
is documented where it is declared.  A blueprint's ``Params`` are dataclass fields (their ``doc``).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import types
import typing
from pathlib import Path
from typing import Any, Iterator, Literal

from annotated_types import Ge, Gt, Le, Lt, MaxLen, MinLen
from pydantic import BaseModel
from pydantic.fields import FieldInfo
from pydantic_core import PydanticUndefined

# Kept to the envelope, the use-case registry and the config modules that it loads.
from pytest_driveeval.scenario.envelope import Envelope
from pytest_driveeval.core.usecase import get_usecase

PAGE = Path(__file__).resolve().parents[2] / "docs" / "reference" / "scenario-keys.md"
COMMAND = "python -m pytest_driveeval.scenario.reference"
# The use cases this package ships (pytest_driveeval/usecases/<name>/); a use case of another
# package documents its own keys.
USECASES = ("closed_loop", "obstacle_segmentation", "policy_benchmark")
# Keys of the envelope that the use case's own table documents instead.
USECASE_KEYS = "Evaluation"


class MissingDescription(Exception):
    """Fields that declare no description, by model and field."""


def _bounds(metadata: list) -> list[str]:
    words = []
    for item in metadata:
        if isinstance(item, FieldInfo):  # Annotated[float, Field(ge=0)]
            words += _bounds(item.metadata)
        for kind, sign in ((Gt, "> {}"), (Ge, ">= {}"), (Lt, "< {}"), (Le, "<= {}")):
            if isinstance(item, kind):
                words.append(sign.format(_number(getattr(item, kind.__name__.lower()))))
        if isinstance(item, MinLen) and item.min_length:
            words.append(f"at least {item.min_length} long")
        if isinstance(item, MaxLen):
            words.append(f"at most {item.max_length} long")
    return words


def _number(value: Any) -> str:
    return f"{value:g}" if isinstance(value, float) else str(value)


def type_name(annotation: Any, metadata: list | None = None) -> str:
    """How the page spells a type: YAML's words (number, text, a list of ...), with its bounds."""
    metadata = list(metadata or [])
    origin = typing.get_origin(annotation)
    args = typing.get_args(annotation)
    if origin is typing.Annotated:
        return type_name(args[0], [*args[1:], *metadata])
    bounds = _bounds(metadata)
    if origin in (typing.Union, types.UnionType):
        kept = [a for a in args if a is not type(None)]
        name = " or ".join(type_name(a) for a in kept)
    elif origin is Literal:
        name = " \\| ".join(f"`{a}`" for a in args)
    elif origin in (list, tuple) and origin is tuple and args and args[-1] is not Ellipsis:
        name = "[" + ", ".join(type_name(a) for a in args) + "]"
    elif origin in (list, tuple, set, frozenset):
        name = f"list of {type_name(args[0]) if args else 'values'}"
    elif origin is dict:
        name = f"mapping of {type_name(args[0])} to {type_name(args[1])}"
    elif isinstance(annotation, type) and issubclass(annotation, BaseModel):
        name = "mapping"
    else:
        name = {int: "integer", float: "number", str: "text", bool: "true \\| false",
                Any: "any"}.get(annotation, getattr(annotation, "__name__", str(annotation)))
    return f"{name} ({', '.join(bounds)})" if bounds else name


def _default(field: FieldInfo) -> str:
    if field.is_required():
        return "required"
    value = field.default_factory() if field.default_factory is not None else field.default
    if value is None or value is PydanticUndefined:
        return "unset"
    if isinstance(value, BaseModel):
        return "its keys' defaults"
    return f"`{_yaml(value)}`"


def _yaml(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return _number(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_yaml(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}: {_yaml(v)}" for k, v in value.items()) + "}"
    return str(value) if not isinstance(value, str) else (value or json.dumps(value))


def _nested(annotation: Any) -> Iterator[tuple[str, type[BaseModel]]]:
    """The models a field holds, with the path step that leads into each: '' (the mapping
    itself), '[]' (each entry of a list), '.<name>' (each value of a mapping)."""
    origin = typing.get_origin(annotation)
    args = typing.get_args(annotation)
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        yield "", annotation
    elif origin is typing.Annotated or origin in (typing.Union, types.UnionType):
        for arg in args:
            yield from _nested(arg)
    elif origin is list and args:
        yield from ((f"[]{step}", model) for step, model in _nested(args[0]))
    elif origin is dict and len(args) == 2:
        yield from ((f".<name>{step}", model) for step, model in _nested(args[1]))


def rows(model: type[BaseModel], prefix: str = "", skip: tuple[str, ...] = ()) -> Iterator[tuple[str, ...]]:
    """(key path, type, default, meaning) of every key of ``model``, depth first."""
    missing = []
    found = []
    for name, field in model.model_fields.items():
        key = field.alias or name
        if key in skip:
            continue
        if not field.description:
            missing.append(f"{model.__module__}.{model.__qualname__}.{name}")
            continue
        path = f"{prefix}{key}"
        found.append((f"`{path}`", type_name(field.annotation, field.metadata), _default(field),
                      " ".join(field.description.split())))
        for step, nested in _nested(field.annotation):
            found.extend(rows(nested, f"{path}{step}."))
    if missing:
        raise MissingDescription(", ".join(missing))
    yield from found


def _table(entries: list[tuple[str, ...]]) -> str:
    lines = ["| key | type | default | meaning |", "|---|---|---|---|"]
    lines += ["| " + " | ".join(cell.replace("|", "\\|") if i in (0, 3) else cell for i, cell in enumerate(entry))
              + " |" for entry in entries]
    return "\n".join(lines) + "\n"


def _parameter_tables(model: type[BaseModel]) -> str:
    """Keys read into dataclasses rather than models (a blueprint's ``Params``): the tables a
    use case's config model names with ``parameter_tables()``, from each field's ``doc``."""
    tables = getattr(model, "parameter_tables", None)
    if tables is None:
        return ""
    out = ["The blueprint's own parameters, given under `Blueprint.Params`:\n"]
    for title, params, only in tables():
        out.append(f"### `Blueprint.Params` of {title}\n\n" + _dataclass_table(params, None if only is None
                                                                                   else set(only)))
    return "\n".join(out)


def _dataclass_table(params: type, only: set[str] | None) -> str:
    entries = []
    hints = typing.get_type_hints(params)
    for field in dataclasses.fields(params):
        if only is not None and field.name not in only:
            continue
        doc = field.metadata.get("doc")
        if not doc:
            raise MissingDescription(f"{params.__module__}.{params.__qualname__}.{field.name}")
        default = field.default if field.default is not dataclasses.MISSING else field.default_factory()
        entries.append((f"`Evaluation.Blueprint.Params.{field.name}`", type_name(hints[field.name]),
                        f"`{_yaml(default)}`", " ".join(doc.split())))
    return _table(entries)


def page() -> str:
    """The whole page, as committed."""
    parts = [
        "# Scenario keys\n",
        f"<!-- Made by `{COMMAND}` from the models that validate the keys; do not edit by hand. -->\n",
        "Every key a scenario file can hold, with its type, its default and what it means.  A key path "
        "`A.B` is key `B` inside the mapping `A`; `A[].B` is key `B` of each entry of the list `A`; "
        "`A.<name>.B` is key `B` of each value of the mapping `A`.  \"unset\" means the key may be left "
        "out and then does nothing of its own (the text says what happens instead).  An unknown key is "
        "an error at its line, with the nearest known key.\n",
        "## Every scenario\n",
        "The envelope, driving_log_replayer's keys and ours in their style "
        "(`pytest_driveeval/scenario/envelope.py`).  The use case that `Evaluation.UseCaseName` names "
        "reads the rest of `Evaluation`.\n",
        _table(list(rows(Envelope))),
    ]
    for name in USECASES:
        usecase = get_usecase(name)
        versions = ", ".join(f"`{v}`" for v in usecase.format_versions)
        parts += [f"## {name}\n",
                  f"`UseCaseName: {name}`, `UseCaseFormatVersion`: {versions} "
                  f"(`{type(usecase).__module__.replace('.', '/')}/config.py`).\n",
                  _table(list(rows(usecase.config_model, "Evaluation.")))]
        extra = _parameter_tables(usecase.config_model)
        if extra:
            parts.append(extra)
    return "\n".join(parts)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--check", action="store_true", help="exit 1 if the committed page differs")
    args = parser.parse_args(argv)
    try:
        text = page()
    except MissingDescription as exc:
        print(f"fields without a description (add description=... where each is declared): {exc}", file=sys.stderr)
        return 2
    if args.check:
        same = PAGE.exists() and PAGE.read_text() == text
        if not same:
            print(f"{PAGE} differs from the models: run {COMMAND}", file=sys.stderr)
        return 0 if same else 1
    PAGE.write_text(text)
    print(f"wrote {PAGE}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
