"""The raster planning model: shapes, TorchScript, and that its first pose follows the image."""
from __future__ import annotations

import pytest

torch = pytest.importorskip("torch")

from pytest_driveeval.policies.raster_model import RasterPlanningModel  # noqa: E402
from conftest import torchscript


def test_output_shapes_and_scripted_model_agree():
    torch.manual_seed(0)
    model = RasterPlanningModel(in_channels=5, raster_size=32, future_frames=4).eval()
    for p in model.head[3].parameters():  # zero-initialised: give the head something to say
        torch.nn.init.normal_(p, std=0.1)
    data = {"image": torch.rand(3, 5, 32, 32)}
    with torch.no_grad():
        out = model(data)
        scripted = torchscript(model)(data)
    assert out["positions"].shape == (3, 4, 2) and out["yaws"].shape == (3, 4, 1)
    torch.testing.assert_close(out["positions"], scripted["positions"])
    # Different images, different plans: the output is a function of the image.
    assert not torch.allclose(out["positions"][0], out["positions"][1])


def test_a_fresh_model_stands_still():
    with torch.no_grad():
        out = RasterPlanningModel(in_channels=3, raster_size=16).eval()({"image": torch.rand(2, 3, 16, 16)})
    assert float(out["positions"].abs().max()) == 0.0


def test_wrong_channel_count_is_named():
    model = RasterPlanningModel(in_channels=25, raster_size=16)
    with pytest.raises(ValueError, match="3 channels, the model was built for 25"):
        model({"image": torch.zeros(1, 3, 16, 16)})


def test_raster_size_must_suit_the_strides():
    with pytest.raises(ValueError, match="raster_size 100"):
        RasterPlanningModel(in_channels=3, raster_size=100)
