"""VGG16's convolutional features, written here (torchvision is not a dependency), and
the lookup of its ImageNet weights.

The layers and their indices are torchvision's ``vgg16().features``, so its state dict
(``features.0.weight`` ... ``features.28.bias``; ``classifier.*`` is ignored) loads
unchanged. Weights are never downloaded: they come from a file the user names or from
torch hub's cache, and their SHA-256 is checked here (torch hub checks a hash only when
it downloads, never for a file already in its cache).
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass

import torch
from torch import nn

from pipeline.errors import ShaderballError, quoted
from pipeline.neural.config import TrainConfig
from pipeline.neural.limits import VGG16_FILE

#: torchvision's VGG16 feature configuration: conv widths, "M" for a 2x2 max pool.
VGG16_CONFIG = (64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512, "M", 512, 512, 512, "M")
#: Index (in ``features``) of the ReLU after conv3_3: the paper's feature layer.
RELU3_3 = 15
#: torch hub's file name for torchvision's VGG16 ImageNet weights (the hash prefix is torch's).
HUB_FILENAME = VGG16_FILE
#: SHA-256 of that file: it begins with the prefix torch hub puts in the name.
VGG16_IMAGENET_SHA256 = "397923af8e79cdbb6a7127f12361acd7a2f83e06b05044ddf496e83de57a5bf0"
#: ImageNet normalisation the weights were trained with (inputs in [0, 1], sRGB).
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


def vgg16_features(upto: int | None = None) -> nn.Sequential:
    """torchvision's ``vgg16().features`` layer for layer, optionally cut after index ``upto``."""
    layers: list[nn.Module] = []
    c_in = 3
    for item in VGG16_CONFIG:
        if item == "M":
            layers.append(nn.MaxPool2d(kernel_size=2, stride=2))
        else:
            layers += [nn.Conv2d(c_in, item, kernel_size=3, padding=1), nn.ReLU(inplace=True)]
            c_in = item
    if upto is not None:
        layers = layers[: upto + 1]
    return nn.Sequential(*layers)


def random_vgg16_state_dict(seed: int) -> dict[str, torch.Tensor]:
    """A randomly initialised VGG16 feature state dict under torchvision's key names
    (``features.N.weight/bias``), for tests: no ImageNet weights can be downloaded here."""
    generator_state = torch.random.get_rng_state()
    try:
        torch.manual_seed(seed)
        features = vgg16_features()
        for module in features:
            if isinstance(module, nn.Conv2d):
                nn.init.kaiming_normal_(module.weight, mode="fan_out", nonlinearity="relu")
                nn.init.zeros_(module.bias)
    finally:
        torch.random.set_rng_state(generator_state)
    return {f"features.{k}": v.clone() for k, v in features.state_dict().items()}


def sha256_of(path: str, chunk_bytes: int = 1 << 20) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(chunk_bytes):
            digest.update(chunk)
    return digest.hexdigest()


def hub_cache_path() -> str:
    """Where torch hub keeps the weights: ``$TORCH_HOME/hub/checkpoints/vgg16-397923af.pth``."""
    return os.path.join(torch.hub.get_dir(), "checkpoints", HUB_FILENAME)


@dataclass(frozen=True)
class VggWeights:
    path: str
    sha256: str
    source: str  # "vgg_weights" (the field: a file the user named) or "torch hub cache"

    def refused(self, what: str, allowed: str) -> ShaderballError:
        """The file refused, naming the field ``vgg_weights`` (given, or unset: torch hub's cache)."""
        where = "" if self.source == "vgg_weights" else "torch hub's cache: "
        return TrainConfig.field_error("vgg_weights", self.path, allowed, what=where + what)


def find_vgg_weights(path: str | None = None, expected_sha256: str | None = None) -> VggWeights:
    """The VGG16 weights file to use, its SHA-256 checked, or a ShaderballError that says
    how to provide one.

    ``expected_sha256`` defaults to torchvision's ImageNet file; name another digest to use
    other weights (the tests use randomly initialised ones).
    """
    expected = (expected_sha256 or VGG16_IMAGENET_SHA256).lower()
    if path is not None:
        source = "vgg_weights"
        if not os.path.isfile(path):
            raise TrainConfig.field_error(
                "vgg_weights",
                path,
                f"torchvision's vgg16 state dict ({HUB_FILENAME})",
                what=f"{quoted(path)} is not a file",
            )
    else:
        source = "torch hub cache"
        path = hub_cache_path()
        if not os.path.isfile(path):
            raise TrainConfig.field_error(
                "vgg_weights",
                None,
                f"name the file, or put {HUB_FILENAME} in torch hub's cache at {path} "
                "($TORCH_HOME/hub/checkpoints/); or train with {loss} l1",
                what="unset, and torch hub's cache holds no VGG16 ImageNet weights: the VGG16 loss needs "
                "torchvision's (they cannot be downloaded here)",
            )
    digest = sha256_of(path)
    weights = VggWeights(path=path, sha256=digest, source=source)
    if digest != expected:
        raise weights.refused(
            f"{quoted(path)} has SHA-256 {digest}, not the expected {expected}"
            + ("" if expected_sha256 else f" of torchvision's {HUB_FILENAME}"),
            "pass {vgg_sha256} with the file's digest to use other VGG16 weights on purpose",
        )
    return weights


def load_vgg16_relu3_3(weights: VggWeights) -> nn.Sequential:
    """VGG16 features up to relu3_3 with the file's weights, frozen, in eval mode."""
    try:
        state = torch.load(weights.path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises several types for a bad file
        raise weights.refused(
            f"{quoted(weights.path)} is not a readable torch state dict ({exc})", "torchvision's vgg16 state dict"
        ) from exc
    if not isinstance(state, dict):
        raise weights.refused(
            f"{quoted(weights.path)} holds a {type(state).__name__}, not a state dict", "torchvision's vgg16 state dict"
        )
    features = vgg16_features(upto=RELU3_3)
    wanted = {f"features.{k}": v for k, v in features.state_dict().items()}
    picked = {}
    for key, ref in wanted.items():
        value = state.get(key)
        if not isinstance(value, torch.Tensor) or value.shape != ref.shape:
            got = None if value is None else tuple(getattr(value, "shape", ()))
            raise weights.refused(
                f"{quoted(weights.path)} is not torchvision's vgg16 state dict: {key} is {got}, expected shape "
                f"{tuple(ref.shape)}",
                f"torchvision's vgg16 state dict ({HUB_FILENAME})",
            )
        picked[key.removeprefix("features.")] = value.float()
    features.load_state_dict(picked)
    features.eval()
    for p in features.parameters():
        p.requires_grad_(False)
    return features
