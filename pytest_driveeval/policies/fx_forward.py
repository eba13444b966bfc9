"""An exported program's forward with less Python between its ATen calls.

The module that ``torch.export.load(...).module()`` returns runs generated
Python that calls each ATen operator through ``OpOverload.__call__`` and reads
each weight through ``nn.Module.__getattr__``.  For a small policy those are
most of a call: the shipped GNN actor makes 113 ATen calls on tensors of a
few thousand numbers, and a robustness search calls it every step of every
batch.  :func:`fast_forward` generates the same sequence of calls from the
graph, calling each overload's C++ entry point (``OpOverload._op``, which is
all ``__call__`` does) and holding the module's weights and constants as
objects bound once.  The kernels, their order and their arguments are the
graph's, so the outputs are the module's bit for bit (tests/policies/test_fx_forward.py).

The weights are bound by identity: ``load_state_dict`` and ``.to()`` update
them in place and stay visible; assigning a new tensor to a module attribute
does not, so :class:`~pytest_driveeval.policies.loading.ExportedModel` builds
the function once, for the inference it runs.
"""
from __future__ import annotations

import keyword
from typing import Any, Callable

__all__ = ["fast_forward"]


def fast_forward(module: Any) -> Callable[..., Any] | None:
    """``module(*args)`` for an exported program's module (a ``torch.fx.GraphModule``) as a plain
    function, or None for a graph this does not handle (a node that calls a tensor's method, or a
    keyword argument whose name is no Python name: a crafted file's, which must not become code)."""
    import torch
    from torch.fx import Node

    graph = module.graph
    nodes = list(graph.nodes)
    if any(n.op not in ("placeholder", "get_attr", "call_function", "call_module", "output") for n in nodes):
        return None
    # The only text of the graph's that goes into the code: keyword names (values are literals or bound).
    if not all(_plain_name(k) for n in nodes for k in n.kwargs):
        return None
    bound: dict[str, Any] = {}

    def bind(value: Any) -> str:
        name = f"_b{len(bound)}"
        bound[name] = value
        return name

    names: dict[Node, str] = {}

    def source(arg: Any) -> str:
        if isinstance(arg, Node):
            return names[arg]
        if isinstance(arg, list):
            return "[" + ", ".join(source(a) for a in arg) + "]"
        if isinstance(arg, tuple):
            return "(" + "".join(source(a) + ", " for a in arg) + ")"
        if isinstance(arg, dict):
            return "{" + ", ".join(f"{source(k)}: {source(v)}" for k, v in arg.items()) + "}"
        if arg is None or type(arg) in (bool, int, str):
            return repr(arg)
        return bind(arg)  # floats (inf, nan), dtypes, devices, layouts, memory formats ...

    last_use = {}
    for i, node in enumerate(nodes):
        for used in node.all_input_nodes:
            last_use[used] = i
    params, lines = [], []
    for i, node in enumerate(nodes):
        if node.op == "placeholder":
            names[node] = f"v{i}"
            params.append(names[node])
        elif node.op == "get_attr":
            names[node] = bind(_attribute(module, node.target))
        elif node.op == "output":
            lines.append(f"    return {source(node.args[0])}")
        else:
            target = _attribute(module, node.target) if node.op == "call_module" else node.target  # export's guards
            call = bind(target._op if isinstance(target, torch._ops.OpOverload) else target)
            args = [source(a) for a in node.args] + [f"{k}={source(v)}" for k, v in node.kwargs.items()]
            names[node] = f"v{i}"
            lines.append(f"    v{i} = {call}({', '.join(args)})")
            # Free intermediates as the generated module does: a large model's peak memory stays its own.
            dead = [names[u] for u in node.all_input_nodes if last_use[u] == i and names[u].startswith("v")]
            if dead:
                lines.append(f"    {' = '.join(dead)} = None")
    code = f"def forward({', '.join(params)}):\n" + "\n".join(lines) + "\n"
    namespace = dict(bound)
    exec(compile(code, "<pytest_driveeval exported forward>", "exec"), namespace)  # our own generated code
    flat_forward = namespace["forward"]
    codegen = graph._codegen  # flattens the call's arguments and rebuilds its outputs as the module does

    def forward(*args: Any) -> Any:
        return codegen.process_outputs(flat_forward(*codegen.process_inputs(*args)))

    return forward


def _plain_name(name: Any) -> bool:
    return isinstance(name, str) and name.isidentifier() and not keyword.iskeyword(name)


def _attribute(module: Any, dotted: str) -> Any:
    for part in dotted.split("."):
        module = getattr(module, part)
    return module
