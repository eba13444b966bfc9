"""An exported program's generated forward (policies.fx_forward) gives its module's outputs bit for
bit, and ExportedModel takes it only for shapes that passed the module's own checks."""
from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from pytest_driveeval.policies.fx_forward import fast_forward  # noqa: E402
from pytest_driveeval.policies.loading import ExportedModel, load_model  # noqa: E402
from pytest_driveeval.sim.episodes import reset  # noqa: E402
from pytest_driveeval.usecases.policy_benchmark.evaluate import observe  # noqa: E402

from conftest import REPO_ROOT  # noqa: E402

MODELS = REPO_ROOT / "fixtures" / "models"


def _exported(module, *args, **kwargs):
    path_free = torch.export.export(module, args, kwargs or None)
    return path_free.module()


@pytest.mark.parametrize("stem", ["gnn_actor_merging", "gnn_actor_highway", "gnn_actor_intersection",
                                  "mlp_actor_merging", "mlp_actor_highway", "mlp_actor_intersection"])
def test_the_shipped_actors_give_their_modules_outputs_bit_for_bit(stem):
    blueprint = stem.rsplit("_", 1)[1]
    module = load_model(str(MODELS / f"{stem}.pt2")).module
    forward = fast_forward(module)
    assert forward is not None
    # Real observations, on the batch sizes a run meets (one episode alone, a search's batch ...).
    flat = observe(reset(blueprint, np.arange(40, 73)), 12)
    with torch.no_grad():
        for rows in (1, 2, 5, 33):
            torch.testing.assert_close(forward(flat[:rows]), module(flat[:rows]), rtol=0, atol=0)


def test_several_inputs_constants_and_a_nested_output():
    class Two(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.lin = torch.nn.Linear(4, 3)
            self.register_buffer("offset", torch.tensor([0.5, -1.0, 2.0]))

        def forward(self, a, b):
            h = self.lin(a) + self.offset
            clipped = torch.clamp(h, max=float("inf"), min=-1.5)
            return {"sum": clipped + b[:, :3], "parts": (h.to(torch.float64), b.sum(dim=1, keepdim=True))}

    torch.manual_seed(0)
    a, b = torch.randn(6, 4), torch.randn(6, 5)
    module = _exported(Two(), a, b)
    forward = fast_forward(module)
    got, want = forward(a, b), module(a, b)
    assert set(got) == {"sum", "parts"} and isinstance(got["parts"], tuple)
    torch.testing.assert_close(got, want, rtol=0, atol=0)
    assert got["parts"][0].dtype == torch.float64


def test_a_graph_with_a_branch_operator():
    class Branch(torch.nn.Module):
        def forward(self, x):
            return torch.cond(x.sum() > 0, lambda t: t * 2.0, lambda t: t - 1.0, (x,))

    module = _exported(Branch(), torch.ones(3))
    forward = fast_forward(module)
    for x in (torch.ones(3), -torch.ones(3)):
        torch.testing.assert_close(forward(x), module(x), rtol=0, atol=0)


def test_weights_loaded_in_place_later_are_seen():
    module = _exported(torch.nn.Linear(3, 2), torch.ones(4, 3))  # a static batch of 4: export guards it
    forward = fast_forward(module)
    x = torch.randn(4, 3)
    state = {k: torch.randn_like(v) for k, v in module.state_dict().items()}
    module.load_state_dict(state)
    torch.testing.assert_close(forward(x), x @ state["weight"].T + state["bias"], rtol=0, atol=0)


def test_a_graph_that_calls_methods_is_left_to_the_module():
    class Method(torch.nn.Module):
        def forward(self, x):
            return x.relu() + 1.0

    traced = torch.fx.symbolic_trace(Method())  # a call_method node
    assert fast_forward(traced) is None
    model = ExportedModel(traced)
    x = torch.tensor([[-1.0, 2.0]])
    model(x)
    torch.testing.assert_close(model(x), traced(x), rtol=0, atol=0)


def test_exported_model_takes_the_generated_forward_only_for_a_shape_that_passed():
    model = load_model(str(MODELS / "gnn_actor_merging.pt2"))
    flat = observe(reset("merging", np.arange(4)), 12)
    with torch.no_grad():
        first = model(flat)
        assert model._forward is None  # the first call of a shape goes through the module's checks
        second = model(flat)
        assert model._forward is not None and model._forward != model.module.forward
    torch.testing.assert_close(first, second, rtol=0, atol=0)
    # A new, wrong width still meets the module's own check, not the generated code.
    with pytest.raises(Exception, match="279"):
        model(torch.zeros(4, 278))


def test_the_export_guards_still_run():
    module = _exported(torch.nn.Linear(3, 2), torch.ones(4, 3))
    forward = fast_forward(module)
    with pytest.raises(AssertionError, match="Guard failed"):
        forward(torch.ones(5, 3))


def test_a_keyword_name_that_is_not_a_name_never_becomes_code(tmp_path):
    module = _exported(torch.nn.Linear(3, 2), torch.ones(4, 3))
    node = next(n for n in module.graph.nodes if n.op == "call_function")
    marker = tmp_path / "ran"
    node.kwargs = {**node.kwargs, f"x=open({str(marker)!r}, 'w'), y": 1}
    assert fast_forward(module) is None
    assert not marker.exists()
