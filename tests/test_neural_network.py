"""The paper's network: parameter count, shapes, light map, init, refused inputs."""

import math

import pytest
import torch

from pipeline.errors import ShaderballError
from pipeline.neural.network import (
    PAPER_PARAMETERS,
    NeuralRenderer,
    check_network_resolution,
    light_input,
    parameter_count,
)

torch.set_num_threads(1)


def test_paper_parameter_count_at_400():
    assert parameter_count(NeuralRenderer(400)) == PAPER_PARAMETERS == 11_752_404


@pytest.mark.parametrize("resolution", [16, 32, 64])
def test_other_resolutions_count_the_light_layer_by_bottleneck_pixels(resolution):
    # only the light branch's last layer depends on R: 256 -> (R/16)^2 outputs
    b2 = (resolution // 16) ** 2
    assert parameter_count(NeuralRenderer(resolution)) == PAPER_PARAMETERS - (256 * 625 + 625) + (256 * b2 + b2)


def test_shapes_through_the_network():
    torch.manual_seed(0)
    model = NeuralRenderer(64).eval()
    seen = {}
    for i, block in enumerate(model.encoder):
        block.register_forward_hook(lambda m, a, out, i=i: seen.__setitem__(f"enc{i}", tuple(out.shape)))
    for i, block in enumerate(model.decoder):
        block.register_forward_hook(lambda m, a, out, i=i: seen.__setitem__(f"dec{i}", tuple(out.shape)))
    model.bottleneck.register_forward_hook(lambda m, a, out: seen.__setitem__("bottleneck", tuple(out.shape)))
    model.bottleneck.register_forward_pre_hook(lambda m, a: seen.__setitem__("bottleneck_in", tuple(a[0].shape)))
    with torch.no_grad():
        out = model(torch.rand(3, 12, 64, 64), torch.rand(3, 4))
    assert out.shape == (3, 3, 64, 64)
    assert seen == {
        "enc0": (3, 64, 32, 32),
        "enc1": (3, 128, 16, 16),
        "enc2": (3, 256, 8, 8),
        "enc3": (3, 512, 4, 4),
        "bottleneck_in": (3, 640, 4, 4),
        "bottleneck": (3, 512, 4, 4),
        "dec0": (3, 512, 8, 8),
        "dec1": (3, 256, 16, 16),
        "dec2": (3, 128, 32, 32),
        "dec3": (3, 64, 64, 64),
    }
    assert float(out.min()) >= 0.0 and float(out.max()) <= 1.0


def test_light_map_is_128_identical_channels_of_the_mlp_output():
    torch.manual_seed(1)
    model = NeuralRenderer(32)
    light = torch.tensor([[0.1, 0.2, 0.9, 3.0], [0.5, -0.5, 0.7, 9.0]])
    lmap = model.light_map(light)
    assert lmap.shape == (2, 128, 2, 2)
    assert torch.equal(lmap, lmap[:, :1].expand_as(lmap))
    assert torch.equal(lmap[:, 0].reshape(2, 4), model.light(light))
    assert not torch.equal(lmap[0], lmap[1])


def test_light_input_is_the_released_demos_encoding():
    v = torch.tensor([[0.6, 0.0, 0.8, 2.5]])
    assert torch.allclose(light_input(v), torch.tensor([[1.8, 0.0, 2.4, 2.5]]))
    assert math.isclose(float(light_input(v)[0, :3].norm()), 3.0, rel_tol=1e-6)


def test_xavier_uniform_init_and_zero_biases():
    torch.manual_seed(2)
    model = NeuralRenderer(32)
    for module in model.modules():
        if isinstance(module, (torch.nn.Conv2d, torch.nn.Linear)):
            module.requires_grad_(False)
            fan_in = module.weight[0].numel()
            fan_out = module.weight.shape[0] * module.weight[0, 0].numel()
            bound = math.sqrt(6.0 / (fan_in + fan_out))
            assert float(module.weight.abs().max()) <= bound
            assert float(module.weight.abs().max()) > 0.9 * bound  # uniform fills its range
            assert torch.count_nonzero(module.bias) == 0


@pytest.mark.parametrize("bad", [0, 8, 50, 400.0, True, 4112])
def test_resolutions_not_divisible_by_16_are_refused(bad):
    with pytest.raises(ShaderballError, match="resolution"):
        check_network_resolution(bad)


def test_wrong_input_shape_is_refused_with_the_expected_shape():
    model = NeuralRenderer(32)
    with pytest.raises(ShaderballError, match=r"\(N, 12, 32, 32\)"):
        model(torch.rand(1, 12, 64, 64), torch.rand(1, 4))
    with pytest.raises(ShaderballError, match="light"):
        model(torch.rand(2, 12, 32, 32), torch.rand(2, 3))


@pytest.mark.slow
def test_forward_at_400():
    torch.manual_seed(0)
    model = NeuralRenderer(400).eval()
    with torch.no_grad():
        out = model(torch.rand(1, 12, 400, 400), torch.rand(1, 4))
    assert out.shape == (1, 3, 400, 400)
