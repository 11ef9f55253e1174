"""VGG16 features, the weights lookup with its SHA-256 check, and the paper's loss.

No ImageNet weights can be downloaded here: a randomly initialised VGG16 is saved under
torchvision's key names and loaded through the same path as the real file."""

import os

import pytest
import torch

from pipeline.errors import ShaderballError
from pipeline.neural.loss import RenderLoss
from pipeline.neural.vgg import (
    HUB_FILENAME,
    RELU3_3,
    find_vgg_weights,
    hub_cache_path,
    load_vgg16_relu3_3,
    random_vgg16_state_dict,
    sha256_of,
    vgg16_features,
)

torch.set_num_threads(1)

#: torchvision's vgg16().features parameters: index -> (out, in) of each 3x3 conv.
TORCHVISION_VGG16_CONVS = {
    0: (64, 3),
    2: (64, 64),
    5: (128, 64),
    7: (128, 128),
    10: (256, 128),
    12: (256, 256),
    14: (256, 256),
    17: (512, 256),
    19: (512, 512),
    21: (512, 512),
    24: (512, 512),
    26: (512, 512),
    28: (512, 512),
}


@pytest.fixture(scope="module")
def vgg_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("vgg") / "random-vgg16.pth"
    state = random_vgg16_state_dict(seed=7)
    state["classifier.6.bias"] = torch.zeros(1000)  # a full torchvision file has these too: ignored
    torch.save(state, path)
    return str(path)


def test_feature_layers_and_keys_are_torchvisions():
    state = vgg16_features().state_dict()
    expected = {}
    for index, (c_out, c_in) in TORCHVISION_VGG16_CONVS.items():
        expected[f"{index}.weight"] = (c_out, c_in, 3, 3)
        expected[f"{index}.bias"] = (c_out,)
    assert {k: tuple(v.shape) for k, v in state.items()} == expected
    assert isinstance(vgg16_features()[RELU3_3], torch.nn.ReLU)
    assert isinstance(vgg16_features()[RELU3_3 - 1], torch.nn.Conv2d) and vgg16_features()[14].out_channels == 256


def test_weights_load_through_the_checked_path(vgg_file):
    weights = find_vgg_weights(vgg_file, expected_sha256=sha256_of(vgg_file))
    vgg = load_vgg16_relu3_3(weights)
    state = torch.load(vgg_file, weights_only=True)
    assert torch.equal(vgg[14].weight, state["features.14.weight"])
    assert len(vgg) == RELU3_3 + 1 and not vgg.training
    assert all(not p.requires_grad for p in vgg.parameters())
    out = vgg(torch.rand(1, 3, 32, 32))
    assert out.shape == (1, 256, 8, 8) and float(out.min()) >= 0


def test_a_file_with_another_hash_is_refused(vgg_file):
    with pytest.raises(ShaderballError, match="SHA-256") as err:
        find_vgg_weights(vgg_file)  # expects torchvision's ImageNet file
    assert str(err.value).startswith("vgg_weights: ")  # the field, by its name (the command line: --vgg-weights)
    assert "vgg_sha256" in str(err.value) and vgg_file in str(err.value)
    with pytest.raises(ShaderballError, match="SHA-256"):
        find_vgg_weights(vgg_file, expected_sha256="0" * 64)


def test_missing_file_is_named(tmp_path):
    with pytest.raises(ShaderballError, match="^vgg_weights: .*nothere.pth"):
        find_vgg_weights(str(tmp_path / "nothere.pth"))


def test_hub_cache_is_looked_up_and_checked(tmp_path, monkeypatch, vgg_file):
    monkeypatch.setenv("TORCH_HOME", str(tmp_path))
    with pytest.raises(ShaderballError) as err:
        find_vgg_weights(None)
    message = str(err.value)
    assert message.startswith("vgg_weights: unset") and "loss l1" in message
    assert os.path.join(str(tmp_path), "hub", "checkpoints", HUB_FILENAME) in message
    os.makedirs(os.path.dirname(hub_cache_path()))
    with open(vgg_file, "rb") as src, open(hub_cache_path(), "wb") as dst:
        dst.write(src.read())
    with pytest.raises(ShaderballError, match="torch hub's cache: .*SHA-256"):
        find_vgg_weights(None)  # a cached file is checked too, unlike torch hub's own lookup
    found = find_vgg_weights(None, expected_sha256=sha256_of(vgg_file))
    assert found.path == hub_cache_path() and found.source == "torch hub cache"


def test_a_file_that_is_not_a_vgg16_state_dict_is_refused(tmp_path):
    bad = tmp_path / "bad.pth"
    torch.save({"features.0.weight": torch.zeros(3, 3)}, bad)
    with pytest.raises(ShaderballError, match="features.0.weight"):
        load_vgg16_relu3_3(find_vgg_weights(str(bad), expected_sha256=sha256_of(str(bad))))
    junk = tmp_path / "junk.pth"
    junk.write_bytes(b"not a torch file")
    with pytest.raises(ShaderballError, match="not a readable torch state dict"):
        load_vgg16_relu3_3(find_vgg_weights(str(junk), expected_sha256=sha256_of(str(junk))))


def test_loss_is_l1_plus_weighted_relu3_3_mse(vgg_file):
    vgg = load_vgg16_relu3_3(find_vgg_weights(vgg_file, expected_sha256=sha256_of(vgg_file)))
    loss = RenderLoss("l1+vgg", vgg, vgg_weight=0.5)
    torch.manual_seed(0)
    pred, target = torch.rand(2, 3, 32, 32), torch.rand(2, 3, 32, 32)
    mean = torch.tensor([0.485, 0.456, 0.406]).view(1, 3, 1, 1)
    std = torch.tensor([0.229, 0.224, 0.225]).view(1, 3, 1, 1)
    feat = ((vgg((pred - mean) / std) - vgg((target - mean) / std)) ** 2).mean()
    expected = (pred - target).abs().mean() + 0.5 * feat
    assert float(loss(pred, target)) == pytest.approx(float(expected), rel=1e-5)
    assert float(feat) > 0
    loss.train()
    assert not loss.vgg.training  # the VGG stays in eval mode
    assert float(RenderLoss("l1")(pred, target)) == pytest.approx(float((pred - target).abs().mean()))


def test_unknown_loss_is_refused():
    with pytest.raises(ShaderballError, match="^loss: "):
        RenderLoss("l3")


def test_the_l2_loss_is_the_mean_squared_error_and_logs_l1_beside():
    torch.manual_seed(0)
    pred, target = torch.rand(2, 3, 8, 8, requires_grad=True), torch.rand(2, 3, 8, 8)
    parts = RenderLoss("l2").parts(pred, target)
    assert float(parts["total"]) == pytest.approx(float(((pred - target) ** 2).mean()))
    assert float(parts["l1"]) == pytest.approx(float((pred - target).abs().mean())) and not parts["l1"].requires_grad
