"""A ``.pt2`` file runs no code of its own: crafted archives, each of which ``torch.export.load``
would let run (issue 34), are refused or defused by ``load_model``, and no marker file appears.

Each case starts from a real archive (the shipped planning model, or a small exported
``torch.cond`` policy) and changes only what an attacker would change.
"""
from __future__ import annotations

import io
import json
import os
import pickle
import zipfile
from pathlib import Path

import pytest

torch = pytest.importorskip("torch")

from conftest import REPO_ROOT  # noqa: E402
from pytest_driveeval.core.errors import ModelError  # noqa: E402
from pytest_driveeval.policies.loading import load_model  # noqa: E402

SHIPPED = REPO_ROOT / "fixtures" / "models" / "planning_model.pt2"
GNN = REPO_ROOT / "fixtures" / "models" / "gnn_actor_merging.pt2"


class _Touch:
    """Unpickling this calls ``os.system('touch <marker>')``: the payload of every case."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def _payload(marker: Path) -> bytes:
    buffer = io.BytesIO()
    # torch.save's zip layout around a pickle whose unpickling runs os.system
    torch.save({"x": _Touch(marker)}, buffer)
    return buffer.getvalue()


def _rewrite(source: Path, target: Path, change) -> Path:
    """Copy the archive, passing each member's (name without root, bytes) through ``change``,
    which returns new bytes, None to drop the member, or a dict of extra members to add."""
    with zipfile.ZipFile(source) as src, zipfile.ZipFile(target, "w", zipfile.ZIP_STORED) as dst:
        root = src.namelist()[0].split("/", 1)[0] + "/"
        extra = change(None, None) or {}
        for info in src.infolist():
            name = info.filename[len(root):]
            data = change(name, src.read(info))
            if data is not None:
                dst.writestr(root + name, data)
        for name, data in extra.items():
            dst.writestr(root + name, data)
    return target


def _edit_json(name_wanted: str, edit):
    def change(name, data):
        if name is None:
            return None
        if name == name_wanted:
            document = json.loads(data)
            edit(document)
            return json.dumps(document).encode()
        return data
    return change


@pytest.fixture
def marker(tmp_path):
    path = tmp_path / "PWNED"
    yield path
    assert not path.exists(), "the archive ran code"


@pytest.fixture(scope="module")
def cond_policy(tmp_path_factory) -> Path:
    class CondPolicy(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.lin = torch.nn.Linear(3, 2)

        def forward(self, x):
            return torch.cond(x.sum() > 0, lambda z: self.lin(z).relu(), lambda z: self.lin(z) * 2, (x,))

    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("cond") / "cond.pt2"
    torch.export.save(torch.export.export(CondPolicy().eval(), (torch.randn(4, 3),)), path)
    return path


def test_sample_inputs_that_would_run_code_are_never_read(tmp_path, marker):
    # torch retries data/sample_inputs/*.pt with weights_only=False when the safe load fails.
    crafted = _rewrite(SHIPPED, tmp_path / "m.pt2", lambda name, data: (
        None if name is None else _payload(marker) if name.startswith("data/sample_inputs/") else data))
    loaded = load_model(str(crafted))
    original = load_model(str(SHIPPED))
    state, reference = loaded.module.state_dict(), original.module.state_dict()
    assert set(state) == set(reference) and all(torch.equal(state[k], reference[k]) for k in state)


@pytest.mark.parametrize("source, config, payload_file", [
    (SHIPPED, "data/weights/model_weights_config.json", "data/weights/weight_0"),
    (GNN, "data/constants/model_constants_config.json", "data/constants/tensor_0"),
])
def test_a_pickled_weight_or_constant_is_refused(tmp_path, marker, source, config, payload_file):
    def change(name, data):
        if name is None:
            return None
        if name == config:
            document = json.loads(data)
            first = next(iter(document["config"].values()))
            first["use_pickle"] = True
            return json.dumps(document).encode()
        return _payload(marker) if name == payload_file else data

    crafted = _rewrite(source, tmp_path / "m.pt2", change)
    with pytest.raises(ModelError, match="use_pickle"):
        load_model(str(crafted))


def test_an_opaque_constant_is_refused(tmp_path, marker):
    def edit(document):
        entry = next(iter(document["config"].values()))
        entry["path_name"] = "opaque_obj_0"

    change = _edit_json("data/constants/model_constants_config.json", edit)
    crafted = _rewrite(GNN, tmp_path / "m.pt2", lambda name, data: (
        {"data/constants/opaque_obj_0": pickle.dumps(_Touch(marker))} if name is None else change(name, data)))
    with pytest.raises(ModelError, match="opaque"):
        load_model(str(crafted))


def test_compiled_code_in_the_archive_is_refused(tmp_path, marker):
    crafted = _rewrite(SHIPPED, tmp_path / "m.pt2", lambda name, data: (
        {"data/aotinductor/model/model.so": b"\x7fELF"} if name is None else data))
    with pytest.raises(ModelError, match="compiled code"):
        load_model(str(crafted))


def _cond_node(document):
    return next(n for n in document["graph_module"]["graph"]["nodes"] if n["target"].endswith("cond"))


def test_a_keyword_name_that_is_code_is_refused_before_torch_generates_the_forward(tmp_path, marker, cond_policy):
    # The case: torch.fx pastes a higher-order op's keyword names into the forward it generates.
    injected = f"**{{'k': __import__('os').system('touch {marker}')}}, z"

    def edit(document):
        _cond_node(document)["inputs"][3]["name"] = injected

    crafted = _rewrite(cond_policy, tmp_path / "m.pt2", _edit_json("models/model.json", edit))
    with pytest.raises(ModelError, match="not a Python name"):
        model = load_model(str(crafted))
        model(torch.randn(4, 3))  # the first step is where the generated forward ran it


def test_the_cond_policy_itself_loads_and_runs_both_branches(cond_policy):
    model = load_model(str(cond_policy))
    reference = torch.export.load(str(cond_policy)).module()
    for x in (torch.ones(4, 3), -torch.ones(4, 3)):
        assert torch.equal(model(x), reference(x))


@pytest.mark.parametrize("target", [
    "torch.serialization.os.system",  # resolves: torch.serialization imports os
    "builtins.exec",
    "torch.ops.higher_order.triton_kernel_wrapper_functional",
    "torch.ops.mylib.anything.default",
])
def test_an_operator_outside_aten_is_refused(tmp_path, marker, cond_policy, target):
    def edit(document):
        node = document["graph_module"]["graph"]["nodes"][0]
        node["target"] = target
        node["inputs"] = [{"name": "command", "arg": {"as_string": f"touch {marker}"}, "kind": 1}]

    crafted = _rewrite(cond_policy, tmp_path / "m.pt2", _edit_json("models/model.json", edit))
    with pytest.raises(ModelError, match="not an operator this loader runs"):
        load_model(str(crafted))(torch.randn(4, 3))


@pytest.mark.parametrize("field, value", [
    # sympy.sympify eval-s a symbolic shape
    ("expr", f"__import__('os').system('touch {{marker}}')"),
    ("range", f"Symbol('s1') + __import__('os').system('touch {{marker}}')"),
    # the guards are pasted into a function that is exec-ed
    ("guard", f"L['x'].size()[0] == __import__('os').system('touch {{marker}}')"),
    ("guard", "L['x'].size()[0] == len('\") or __import__(\"os\")')"),
    # a pytree key ends up in the guards' code and their message
    ("spec", "x\" + __import__('os').system('touch {marker}') + \""),
    ("node_name", "x; __import__('os').system('touch {marker}')"),
    ("stack_trace_kept", None),
])
def test_text_torch_would_evaluate_is_refused(tmp_path, marker, field, value):
    value = value.format(marker=marker) if value else value

    def edit(document):
        module = document["graph_module"]
        if field == "expr":
            next(iter(module["graph"]["sym_int_values"].values()))["as_expr"]["expr_str"] = value
        elif field == "range":
            document["range_constraints"][value] = next(iter(document["range_constraints"].values()))
        elif field == "guard":
            document["guards_code"].append(value)
        elif field == "spec":
            signature = module["module_call_graph"][0]["signature"]
            signature["in_spec"] = _rename_key(signature["in_spec"], "history_positions", value)
        elif field == "node_name":
            module["graph"]["nodes"][0]["name"] = value
        elif field == "stack_trace_kept":
            module["graph"]["nodes"][0]["metadata"]["stack_trace"] = f"\nimport os; os.system('touch {marker}')\n"

    crafted = _rewrite(SHIPPED, tmp_path / "m.pt2", _edit_json("models/model.json", edit))
    if field == "stack_trace_kept":
        # Node metadata is dropped, not refused: the model loads, and the text is in none of its code.
        model = load_model(str(crafted))
        assert "os.system" not in model.module.code
        return
    with pytest.raises(ModelError, match="refused exported program"):
        load_model(str(crafted))


def _rename_key(spec: str, old: str, new: str) -> str:
    """A pytree spec (JSON, whose dict contexts are JSON again) with one dict key renamed."""
    def visit(node):
        if isinstance(node, list):
            return [visit(item) for item in node]
        if isinstance(node, dict):
            node = dict(node)
            if isinstance(node.get("context"), str) and old in node["context"]:
                node["context"] = json.dumps([new if key == old else key for key in json.loads(node["context"])])
            node["children_spec"] = visit(node.get("children_spec") or [])
        return node

    renamed = json.dumps(visit(json.loads(spec)))
    contexts = []

    def collect(node):
        if isinstance(node, list):
            [collect(item) for item in node]
        elif isinstance(node, dict):
            contexts.append(json.loads(node["context"]) if isinstance(node.get("context"), str) else None)
            collect(node.get("children_spec") or [])

    collect(json.loads(renamed))
    assert any(isinstance(c, list) and new in c for c in contexts)  # the crafted key is really in the file
    return renamed


def test_a_file_that_is_no_archive_is_a_clear_error(tmp_path):
    (tmp_path / "m.pt2").write_bytes(pickle.dumps({"not": "a zip"}))
    with pytest.raises(ModelError, match="not a .pt2 archive"):
        load_model(str(tmp_path / "m.pt2"))


def test_a_program_nested_past_the_recursion_limit_is_a_clear_error(tmp_path):
    deep = "[" * 5000 + "]" * 5000  # past the recursion limit: neither json nor the walk may end in a bare RecursionError

    def change(name, data):
        if name == "models/model.json":
            document = json.loads(data)
            document["graph_module"]["graph"]["nodes"][0]["inputs"][0]["arg"] = {"as_ints": "DEEP"}
            return json.dumps(document).replace('"DEEP"', deep).encode()
        return data

    crafted = _rewrite(GNN, tmp_path / "m.pt2", lambda name, data: None if name is None else change(name, data))
    with pytest.raises(ModelError, match="nests deeper|not JSON torch writes"):
        load_model(str(crafted))
