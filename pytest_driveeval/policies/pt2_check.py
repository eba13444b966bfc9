"""What a ``.pt2`` archive's serialised program may say before torch turns any of it into code.

torch's loader reads ``models/<name>.json`` and, from its text, builds Python it then runs:
torch.fx pastes node names and keyword names into a generated ``forward``; the guards in
``guards_code`` are pasted into a function and ``exec``-ed; symbolic shapes (``expr_str``,
``range_constraints``) go through ``sympy.sympify``, which ``eval``-s; a node's ``target``
is resolved by ``getattr`` from ``torch``, ``math`` or ``operator`` (``torch.serialization.os.system``
resolves too).  So every string of the program is checked here against the forms torch itself
writes (names, operator paths, sympy's ``srepr`` of a shape, ``L['x'].size()[1] == 7`` guards)
and refused otherwise, before torch sees it.  Node metadata (stack traces, module stacks) is
dropped: nothing we run reads it, and fx copies stack traces into the generated code.

:func:`check_program` raises :class:`ProgramRefused` naming the JSON path of the first
offending value; :func:`allowed_target` is the same rule for an operator torch already resolved.
"""
from __future__ import annotations

import ast
import json
import keyword
import math
import operator
import re
from typing import Any, Callable

__all__ = ["ProgramRefused", "check_program", "allowed_target", "HIGHER_ORDER_OPS"]


class ProgramRefused(ValueError):
    """The serialised program holds something torch would not write, that would become code."""


# Higher-order operators that take subgraphs of the same program and nothing else from the file.
HIGHER_ORDER_OPS = frozenset({
    "cond", "while_loop", "map_impl", "scan", "associative_scan",
    "wrap_with_set_grad_enabled", "wrap_with_autocast", "invoke_subgraph",
})
_OP_NAMESPACES = ("aten", "prims")
_OPERATOR_FUNCS = frozenset({
    "getitem", "add", "sub", "mul", "floordiv", "truediv", "mod", "pow", "neg", "pos", "abs",
    "eq", "ne", "lt", "le", "gt", "ge", "and_", "or_", "xor", "not_", "invert", "lshift", "rshift",
})
_MATH_FUNCS = frozenset({"ceil", "floor", "trunc", "sqrt"})
_TORCH_SYM_FUNCS = frozenset({
    "sym_float", "sym_int", "sym_max", "sym_min", "sym_not", "sym_ite", "sym_sqrt", "sym_sum", "_sym_sqrt",
})
_TARGET = re.compile(
    r"torch\.ops\.(?:aten|prims)\.[A-Za-z_]\w*\.[A-Za-z_]\w*"
    r"|torch\.ops\.higher_order\.(?P<hop>[A-Za-z_]\w*)"
    r"|_operator\.(?P<operator>[a-z_]+)|math\.(?P<math>[a-z]+)|torch\.(?P<sym>_?sym_[a-z_]+)")

_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
_DOTTED = re.compile(r"[A-Za-z0-9_]+(?:\.[A-Za-z0-9_]+)*")
_PLAIN_TEXT = re.compile(r"[\w.\-+: ]*")  # a field this module does not know: no quotes, brackets or newlines

# Fields whose value is free text that torch only ever passes to code as a value (repr'd).
_VALUE_FIELDS = frozenset({"as_string", "as_strings", "torch_version"})
_NAME_FIELDS = frozenset({"name", "as_name", "user_input_name", "arg_name"})
_DOTTED_FIELDS = frozenset({"parameter_name", "buffer_name", "tensor_constant_name", "fqn"})
# Dicts keyed by node names.
_NAME_KEYED = frozenset({"tensor_values", "sym_int_values", "sym_bool_values", "sym_float_values",
                         "as_string_to_argument", "opset_version"})


def check_program(program: dict) -> dict:
    """Check a ``models/<name>.json`` document (already parsed) and return it without node
    metadata; raise :class:`ProgramRefused` at the first value torch would turn into code unchecked."""
    if not isinstance(program, dict) or not isinstance(program.get("graph_module"), dict):
        raise ProgramRefused("it holds no graph_module: not a program torch.export.save writes")
    for i, guard in enumerate(program.get("guards_code") or []):
        _check_guard(guard, f"guards_code[{i}]")
    for key in program.get("range_constraints") or {}:
        _check_sympy(key, f"range_constraints key {key!r}")
    for i, verifier in enumerate(program.get("verifiers") or []):
        if not (isinstance(verifier, str) and re.fullmatch(r"[A-Z_]*", verifier)):
            raise ProgramRefused(f"verifiers[{i}] = {verifier!r} is not a verifier dialect torch writes")
    module = dict(program["graph_module"])
    module["metadata"] = {}  # 'custom' only; json that nothing here reads
    _strip_node_metadata(module.get("graph"))
    _walk(module, "graph_module")
    return {**program, "graph_module": module}


def allowed_target(target: Any) -> bool:
    """Whether a resolved ``call_function`` target is one :func:`check_program` admits by name:
    an ATen or prims overload, a listed higher-order operator, or a listed ``operator`` / ``math`` /
    ``torch.sym_*`` function (the same objects, not look-alikes)."""
    import torch

    if isinstance(target, torch._ops.OpOverload):
        return target.namespace in _OP_NAMESPACES
    if isinstance(target, torch._ops.HigherOrderOperator):
        return target.name() in HIGHER_ORDER_OPS
    allowed = ([getattr(operator, n) for n in _OPERATOR_FUNCS] + [getattr(math, n) for n in _MATH_FUNCS]
               + [getattr(torch, n) for n in _TORCH_SYM_FUNCS if hasattr(torch, n)])
    return any(target is f for f in allowed)


def _strip_node_metadata(graph: Any) -> None:
    if not isinstance(graph, dict):
        return
    for node in graph.get("nodes") or []:
        if isinstance(node, dict):
            node["metadata"] = {}
            for named in node.get("inputs") or []:
                sub = named.get("arg", {}).get("as_graph") if isinstance(named, dict) else None
                if isinstance(sub, dict):
                    _strip_node_metadata(sub.get("graph"))


def _walk(value: Any, path: str, field: str = "") -> None:
    if isinstance(value, dict):
        for key, item in value.items():
            if not isinstance(key, str):
                raise ProgramRefused(f"{path}: a key that is not text")
            where = f"{path}.{key}"
            if field in _NAME_KEYED:
                _check_name(key, f"{path} key {key!r}")
                _walk(item, where, "")
            elif key == "treespec_namedtuple_fields":
                for type_name, fields in (item or {}).items():
                    _check_dotted(type_name, f"{where} key {type_name!r}")
                    _walk(fields, f"{where}.{type_name}", "")
            else:
                _check_field(key, item, where)
                _walk(item, where, key)
    elif isinstance(value, list):
        for i, item in enumerate(value):
            _walk(item, f"{path}[{i}]", field)
    elif isinstance(value, str):
        _check_text(field, value, path)
    elif not (value is None or isinstance(value, (bool, int, float))):
        raise ProgramRefused(f"{path}: a {type(value).__name__}, not a JSON value")


def _check_field(key: str, item: Any, where: str) -> None:
    """Checks that need the whole value of a field (its strings are checked by ``_walk`` after)."""
    if key == "as_custom_obj" or (key == "custom_obj_values" and item):
        raise ProgramRefused(f"{where}: a custom (TorchBind) object, which loading would have to unpickle")
    if key in ("in_spec", "out_spec") and item is not None:
        _check_treespec(item, where)


def _check_text(field: str, text: str, path: str) -> None:
    if field in _VALUE_FIELDS:
        return
    if field in _NAME_FIELDS or field in ("forward_arg_names", "field_names"):
        _check_name(text, path, empty_ok=field == "name")
    elif field in _DOTTED_FIELDS:
        if text:
            _check_dotted(text, path)
    elif field in ("target", "as_operator"):
        _check_target(text, path)
    elif field == "expr_str":
        _check_sympy(text, path)
    elif field in ("in_spec", "out_spec"):
        pass  # parsed and checked whole in _check_field
    elif not _PLAIN_TEXT.fullmatch(text):
        raise ProgramRefused(f"{path} = {text[:80]!r} is text torch does not write there")


def _check_name(text: Any, path: str, *, empty_ok: bool = False) -> None:
    if empty_ok and text == "":
        return
    if not (isinstance(text, str) and _NAME.fullmatch(text) and not keyword.iskeyword(text)):
        raise ProgramRefused(f"{path} = {str(text)[:80]!r} is not a Python name, as torch writes names")


def _check_dotted(text: str, path: str) -> None:
    if not _DOTTED.fullmatch(text):
        raise ProgramRefused(f"{path} = {text[:80]!r} is not a dotted module path")


def _check_target(text: str, path: str) -> None:
    match = _TARGET.fullmatch(text)
    ok = bool(match) and (
        (match["hop"] is None or match["hop"] in HIGHER_ORDER_OPS)
        and (match["operator"] is None or match["operator"] in _OPERATOR_FUNCS)
        and (match["math"] is None or match["math"] in _MATH_FUNCS)
        and (match["sym"] is None or match["sym"] in _TORCH_SYM_FUNCS))
    if not ok:
        raise ProgramRefused(
            f"{path} = {text[:80]!r} is not an operator this loader runs (ATen and prims overloads, "
            f"the higher-order operators {', '.join(sorted(HIGHER_ORDER_OPS))}, and a few of "
            "operator, math and torch.sym_*)")


def _check_treespec(spec: Any, path: str) -> None:
    try:
        tree = json.loads(spec)
    except (TypeError, ValueError, RecursionError):
        raise ProgramRefused(f"{path} is not a pytree spec torch writes") from None

    def visit(node: Any) -> None:
        if isinstance(node, list):
            for item in node:
                visit(item)
        elif isinstance(node, dict):
            if node.get("type") is not None:
                _check_dotted(str(node["type"]), f"{path} type")
            context = node.get("context")
            if isinstance(context, str):
                try:
                    context = json.loads(context)
                except ValueError:
                    raise ProgramRefused(f"{path}: a context that is not JSON") from None
            for text in _strings(context):
                # dict keys and namedtuple type names: they end up in guard code and messages
                _check_dotted(text, f"{path} context") if "." in text else _check_name(text, f"{path} context")
            visit(node.get("children_spec") or [])
        elif not (node is None or isinstance(node, int)):
            raise ProgramRefused(f"{path} is not a pytree spec torch writes")

    visit(tree)


def _strings(value: Any) -> list[str]:
    if isinstance(value, str):
        return [value]
    if isinstance(value, (list, tuple)):
        return [s for item in value for s in _strings(item)]
    if isinstance(value, dict):
        return [s for item in list(value) + list(value.values()) for s in _strings(item)]
    return []


# sympy's srepr of a shape expression: constructors of the expression classes, symbol names,
# numbers and the assumptions as keywords.  sympify eval-s the text, so anything else is refused.
_SYMPY_CALLS = frozenset({
    "Symbol", "Integer", "Float", "Rational", "Add", "Mul", "Pow", "Mod", "Min", "Max", "Abs",
    "floor", "ceiling", "Eq", "Ne", "Lt", "Le", "Gt", "Ge", "StrictLessThan", "StrictGreaterThan",
    "LessThan", "GreaterThan", "Equality", "Unequality", "And", "Or", "Not", "Piecewise", "ExprCondPair",
    "FloorDiv", "ModularIndexing", "Where", "PythonMod", "CleanDiv", "CeilToInt", "FloorToInt", "CeilDiv",
    "LShift", "RShift", "PowByNatural", "FloatPow", "FloatTrueDiv", "IntTrueDiv",
    "IsNonOverlappingAndDenseIndicator", "TruncToFloat", "TruncToInt", "RoundToInt", "RoundDecimal",
    "ToFloat", "Identity", "BitwiseFn_bitwise_and", "BitwiseFn_bitwise_or",
})
_SYMPY_NAMES = _SYMPY_CALLS | {"oo", "zoo", "nan", "true", "false", "S", "Half", "One", "Zero", "NegativeOne",
                               "Infinity", "NegativeInfinity", "int_oo", "IntInfinity", "NegativeIntInfinity"}
_SYMBOL = re.compile(r"[a-z]+[0-9]+|[a-z]")
_ASSUMPTIONS = frozenset({"positive", "negative", "integer", "real", "nonnegative", "nonpositive", "finite",
                          "zero", "nonzero", "evaluate", "precision"})


# Node kinds both expression forms admit: arithmetic, comparisons and boolean logic.
_ARITHMETIC = (ast.Expression, ast.Load, ast.operator, ast.unaryop, ast.cmpop, ast.boolop,
               ast.BinOp, ast.UnaryOp, ast.Compare, ast.BoolOp)


def _check_expression(text: Any, path: str, what: str, allowed: Callable[[ast.AST], bool]) -> None:
    """Parse ``text`` as one Python expression and refuse it unless ``allowed`` admits every node."""
    if not isinstance(text, str) or len(text) > 100_000:
        raise ProgramRefused(f"{path} is not {what} torch writes")
    try:
        tree = ast.parse(text, mode="eval")
    except (SyntaxError, ValueError, RecursionError, MemoryError):
        raise ProgramRefused(f"{path} = {text[:80]!r} is not {what} torch writes") from None
    if not all(allowed(node) for node in ast.walk(tree)):
        raise ProgramRefused(f"{path} = {text[:80]!r} is not {what} torch writes")


def _sympy_node(node: ast.AST) -> bool:
    if isinstance(node, ast.Call):
        return isinstance(node.func, ast.Name) and node.func.id in _SYMPY_CALLS
    if isinstance(node, ast.Name):
        return node.id in _SYMPY_NAMES or bool(_SYMBOL.fullmatch(node.id)) or node.id in ("True", "False")
    if isinstance(node, ast.Constant):
        return isinstance(node.value, (int, float, bool)) or (
            isinstance(node.value, str) and bool(re.fullmatch(r"[a-z]+[0-9]*|-?[0-9.e+\-]+", node.value)))
    if isinstance(node, ast.keyword):
        return node.arg in _ASSUMPTIONS
    if isinstance(node, ast.BinOp):
        return isinstance(node.op, (ast.Add, ast.Sub, ast.Mult, ast.Div, ast.FloorDiv, ast.Mod, ast.Pow))
    return isinstance(node, _ARITHMETIC)


def _guard_node(node: ast.AST) -> bool:
    if isinstance(node, ast.Name):
        return node.id in ("L", "min", "max", "abs")
    if isinstance(node, ast.Attribute):
        return node.attr in ("size", "stride", "storage_offset", "dim", "numel")
    if isinstance(node, ast.Call):
        return (isinstance(node.func, ast.Attribute) and not node.args and not node.keywords) or (
            isinstance(node.func, ast.Name) and node.func.id in ("min", "max", "abs") and not node.keywords)
    if isinstance(node, ast.Constant):
        # Subscript keys of the inputs (they are pasted into a message between double quotes).
        return isinstance(node.value, (int, float, bool)) or (
            isinstance(node.value, str) and bool(_NAME.fullmatch(node.value)))
    return isinstance(node, (*_ARITHMETIC, ast.Subscript))


def _check_sympy(text: Any, path: str) -> None:
    _check_expression(text, path, "a symbolic shape", _sympy_node)


def _check_guard(text: Any, path: str) -> None:
    """A guard is an arithmetic comparison of input sizes: ``L['data']['x'].size()[1] == 11``."""
    _check_expression(text, path, "a shape guard", _guard_node)
