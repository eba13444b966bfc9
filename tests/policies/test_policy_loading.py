"""Models load from TorchScript, state_dict + factory, or a factory; pickle only by name."""
from __future__ import annotations

import pytest

torch = pytest.importorskip("torch")

from pytest_driveeval.core.errors import ModelError  # noqa: E402
from pytest_driveeval.policies.loading import load_model, model_files, names_factory, runs_code  # noqa: E402
from conftest import save_torchscript


class Doubler(torch.nn.Module):
    def __init__(self):
        super().__init__()
        self.scale = torch.nn.Parameter(torch.tensor(2.0))

    def forward(self, x):
        return x * self.scale


def make_doubler() -> Doubler:
    return Doubler()


def test_torchscript_archive(tmp_path):
    model = Doubler()
    with torch.no_grad():
        model.scale.fill_(5.0)
    save_torchscript(model, tmp_path / "m.pt")
    loaded = load_model("m.pt", base=tmp_path)
    with torch.no_grad():
        assert float(loaded(torch.tensor(1.0))) == 5.0
    assert not loaded.training


def test_exported_program(tmp_path):
    program = torch.export.export(Doubler(), (torch.tensor([1.0, 2.0]),))
    torch.export.save(program, tmp_path / "m.pt2")
    loaded = load_model(str(tmp_path / "m.pt2"))
    assert loaded(torch.tensor([1.0, 3.0])).tolist() == [2.0, 6.0]


def test_state_dict_with_factory(tmp_path):
    model = Doubler()
    with torch.no_grad():
        model.scale.fill_(3.0)
    torch.save(model.state_dict(), tmp_path / "w.pt")
    loaded = load_model(f"{tmp_path / 'w.pt'}=test_policy_loading:make_doubler")
    with torch.no_grad():
        assert float(loaded(torch.tensor(2.0))) == 6.0


def test_factory_only():
    with torch.no_grad():
        assert float(load_model("test_policy_loading:make_doubler")(torch.tensor(1.0))) == 2.0


def test_factory_in_a_dotted_module():
    # Path("pytest_driveeval.policies.gnn:make_actor").suffix is ".gnn:make_actor": not a file name.
    assert runs_code("pytest_driveeval.policies.gnn:make_actor")
    assert model_files("pytest_driveeval.policies.gnn:make_actor") == ()
    actor = load_model("pytest_driveeval.policies.gnn:make_actor")
    assert isinstance(actor, torch.nn.Module) and not actor.training


@pytest.mark.parametrize("spec", ["models:v2.pt2", "a.b:c.pt", "C:/models/actor.pt2", "./pkg:f", "pkg:"])
def test_a_colon_in_a_file_name_is_not_a_factory(tmp_path, spec):
    assert not names_factory(spec) and not runs_code(spec)
    with pytest.raises(ModelError, match="model file not found"):
        load_model(spec, base=tmp_path)


def test_whole_pickled_model_needs_the_pickle_prefix(tmp_path):
    torch.save(Doubler(), tmp_path / "whole.pt")
    with pytest.raises(ModelError, match=r"not a TorchScript archive.*'pickle:.*whole.pt'"):
        load_model(str(tmp_path / "whole.pt"))
    loaded = load_model(f"pickle:{tmp_path / 'whole.pt'}")
    with torch.no_grad():
        assert float(loaded(torch.tensor(1.0))) == 2.0


def test_state_dict_refuses_pickled_code(tmp_path):
    torch.save({"model": Doubler()}, tmp_path / "sneaky.pt")
    with pytest.raises(ModelError, match=r"weights_only=True"):
        load_model(f"{tmp_path / 'sneaky.pt'}=test_policy_loading:make_doubler")


@pytest.mark.parametrize("spec, message", [
    ("absent.pt", r"model file not found: .*absent.pt"),
    ("no_such_module_x:f", r"cannot import 'no_such_module_x'"),
    ("test_policy_loading:nothing", r"has no attribute 'nothing'"),
])
def test_clear_errors(tmp_path, spec, message):
    with pytest.raises(ModelError, match=message):
        load_model(spec, base=tmp_path)


def test_weights_that_do_not_fit(tmp_path):
    torch.save({"other": torch.zeros(3)}, tmp_path / "w.pt")
    with pytest.raises(ModelError, match=r"do not fit test_policy_loading:make_doubler"):
        load_model(f"{tmp_path / 'w.pt'}=test_policy_loading:make_doubler")
