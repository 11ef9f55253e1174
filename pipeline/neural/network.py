"""The paper's network, as the authors' released inference code defines it.

A U-Net: four stride-2 encoder blocks (12 -> 64 -> 128 -> 256 -> 512 channels,
R -> R/2 -> R/4 -> R/8 -> R/16 pixels), a light branch (an MLP from the 4-vector to one
value per bottleneck pixel, repeated as 128 identical channels), a bottleneck conv over
the concatenation, and four decoder blocks that each concatenate the encoder's skip at
the lower resolution, upsample bilinearly x2, convolve, batch-normalise and ReLU; an
output conv and a sigmoid give an RGB image in [0, 1].

At the paper's 400x400 the light branch's last layer has 625 = 25 x 25 outputs and the
network has exactly 11,752,404 parameters. At another resolution R (divisible by 16) the
last light layer has (R/16)^2 outputs, reshaped to R/16 x R/16: the light map always
covers the bottleneck one value per pixel, so the parameter count depends on R (e.g.
11,595,891 at 64x64).

``width`` scales every convolution's channels and the light map's copies (the paper's
network: 1.0): a narrower network for CPU-scale runs (at 0.5 about a quarter of
the convolutions' work). The light branch's MLP is the paper's at every width.

Two additions, both off by default (the paper's network, its weights' names and shapes, as
before): ``extra_channels`` input channels after the 12 maps (``train --geometry``: the
geometry normal and depth, :mod:`pipeline.neural.scene_inputs`), and a learned code per
environment map (``environment_codes`` maps, ``code_size`` numbers each, an embedding whose row 0
stands for "no map the run knows": sun-lit samples and unseen maps) concatenated to the light
input before the light branch. :func:`network_from_config` builds the one a run's config.json
describes, so train, evaluate, infer and the checkpoint check agree.
"""

from __future__ import annotations

import contextlib

import torch
from torch import nn
from torch.nn import functional as F

from pipeline.fields import FieldError
from pipeline.neural.limits import ENVIRONMENT_CODE_RANGE, MAX_ENVIRONMENT_CODES, WIDTH_RANGE

#: Input channels in order: diffuse RGB, specular RGB, normal-map colour RGB, roughness x3.
INPUT_CHANNELS = 12
#: The lighting input: 4 values (see :func:`light_input`).
LIGHT_CHANNELS = 4
#: Identical copies of the light map concatenated to the encoder's output.
LIGHT_MAP_CHANNELS = 128
ENCODER_CHANNELS = (64, 128, 256, 512)
#: Length of the sun direction in the network's light input (the released demo's 3).
SUN_DIRECTION_SCALE = 3.0
PAPER_RESOLUTION = 400
#: Extra input channels a run may have: none, or the geometry buffers (normal 3 + depth 1).
EXTRA_CHANNEL_CHOICES = (0, 4)
MAX_CODE_SIZE = ENVIRONMENT_CODE_RANGE[1]
PAPER_PARAMETERS = 11_752_404


def check_width(width, where: str = "width") -> float:
    """Channel fractions the network accepts: (0, 1], giving at least 1 channel per layer;
    ``where`` names the value (a field, or a file's field)."""
    lo, hi = WIDTH_RANGE
    if isinstance(width, bool) or not isinstance(width, (int, float)) or not lo < width <= hi:
        raise FieldError(
            where, width, f"a fraction of the paper's channels in ({lo:g}, {hi:g}] (1: the paper's network)"
        )
    return float(width)


def scaled_channels(channels: int, width: float) -> int:
    return max(1, round(channels * width))


def check_network_resolution(resolution, where: str = "resolution") -> int:
    """Resolutions the network accepts: multiples of 16 from 16 to 4096 (a request's field is
    checked by its rule, pipeline.neural.config.NetworkResolution); ``where`` names the value."""
    if (
        isinstance(resolution, bool)
        or not isinstance(resolution, int)
        or resolution < 16
        or resolution > 4096
        or resolution % 16
    ):
        raise FieldError(where, resolution, "an integer multiple of 16 from 16 to 4096 (the encoder halves it 4 times)")
    return resolution


def light_input(lighting_vector: torch.Tensor) -> torch.Tensor:
    """The dataset's lighting vector (unit sun direction, turbidity) -> the network's input.

    As the released demo: the direction scaled to length 3, turbidity raw (1 to 10).
    Works on (..., 4) tensors; the dataset's stored ``lighting_vector`` is the only source.
    """
    scale = torch.tensor([SUN_DIRECTION_SCALE] * 3 + [1.0], dtype=lighting_vector.dtype, device=lighting_vector.device)
    return lighting_vector * scale


def _conv_bn_relu(c_in: int, c_out: int, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(c_in, c_out, kernel_size=3, stride=stride, padding=1),
        nn.BatchNorm2d(c_out),
        nn.ReLU(inplace=True),
    )


class DecoderBlock(nn.Module):
    """concat(x, skip) at the lower resolution, bilinear x2, conv 3x3, BN, ReLU."""

    def __init__(self, c_in: int, c_skip: int, c_out: int):
        super().__init__()
        self.conv = _conv_bn_relu(c_in + c_skip, c_out)

    def forward(self, x: torch.Tensor, skip: torch.Tensor) -> torch.Tensor:
        x = torch.cat([x, skip], dim=1)
        x = F.interpolate(x, scale_factor=2, mode="bilinear", align_corners=False)
        return self.conv(x)


class NeuralRenderer(nn.Module):
    """12-channel maps (N, 12, R, R) in [0, 1] and light input (N, 4) -> RGB (N, 3, R, R) in [0, 1]."""

    def __init__(
        self,
        resolution: int = PAPER_RESOLUTION,
        width: float = 1.0,
        extra_channels: int = 0,
        environment_codes: int = 0,
        code_size: int = 0,
    ):
        super().__init__()
        self.resolution = check_network_resolution(resolution)
        self.width = check_width(width, "width")
        self.input_channels = INPUT_CHANNELS + int(extra_channels)
        self.code_size = int(code_size) if environment_codes else 0
        # row 0: no known map (a sun-lit sample, a map the run never saw)
        self.environment = nn.Embedding(int(environment_codes) + 1, self.code_size) if self.code_size else None
        self.bottleneck_size = resolution // 16
        e1, e2, e3, e4 = (scaled_channels(c, self.width) for c in ENCODER_CHANNELS)
        self.light_channels = scaled_channels(LIGHT_MAP_CHANNELS, self.width)
        self.light = nn.Sequential(
            nn.Linear(LIGHT_CHANNELS + self.code_size, 32),
            nn.Tanh(),
            nn.Linear(32, 128),
            nn.Tanh(),
            nn.Linear(128, 256),
            nn.Tanh(),
            nn.Linear(256, self.bottleneck_size**2),
            nn.Tanh(),
        )
        self.encoder = nn.ModuleList(
            [
                _conv_bn_relu(self.input_channels, e1, stride=2),
                _conv_bn_relu(e1, e2, stride=2),
                _conv_bn_relu(e2, e3, stride=2),
                _conv_bn_relu(e3, e4, stride=2),
            ]
        )
        self.bottleneck = _conv_bn_relu(e4 + self.light_channels, e4)
        self.decoder = nn.ModuleList(
            [
                DecoderBlock(e4, e4, e4),
                DecoderBlock(e4, e3, e3),
                DecoderBlock(e3, e2, e2),
                DecoderBlock(e2, e1, e1),
            ]
        )
        self.output = nn.Conv2d(e1, 3, kernel_size=3, padding=1)
        self.reset_parameters()

    def reset_parameters(self) -> None:
        """Xavier-uniform weights, zero biases (BatchNorm: weight 1, bias 0)."""
        for module in self.modules():
            if isinstance(module, (nn.Conv2d, nn.Linear)):
                nn.init.xavier_uniform_(module.weight)
                nn.init.zeros_(module.bias)
            elif isinstance(module, nn.BatchNorm2d):
                module.reset_parameters()
            elif isinstance(module, nn.Embedding):
                nn.init.normal_(module.weight, std=0.1)  # small: the light vector stays the main input

    def light_map(self, light: torch.Tensor) -> torch.Tensor:
        """(N, 4) network light input -> (N, C, R/16, R/16), C identical channels (128 at width 1)."""
        b = self.bottleneck_size
        plane = self.light(light).view(-1, 1, b, b)
        return plane.expand(-1, self.light_channels, b, b)

    def forward(self, maps: torch.Tensor, light: torch.Tensor, environment: torch.Tensor | None = None) -> torch.Tensor:
        """``environment``: (N,) indices into the environment codes (None: row 0 for all), used
        only by a network that has codes."""
        r, c = self.resolution, self.input_channels
        if maps.dim() != 4 or maps.shape[1:] != (c, r, r):
            raise FieldError("network input", tuple(maps.shape), f"(N, {c}, {r}, {r})")
        if light.shape != (maps.shape[0], LIGHT_CHANNELS):
            raise FieldError("network light input", tuple(light.shape), f"({maps.shape[0]}, {LIGHT_CHANNELS})")
        if self.environment is not None:
            if environment is None:
                environment = torch.zeros(maps.shape[0], dtype=torch.long, device=maps.device)
            light = torch.cat([light, self.environment(environment).to(light.dtype)], dim=1)
        skips = []
        x = maps
        for block in self.encoder:
            x = block(x)
            skips.append(x)
        x = self.bottleneck(torch.cat([x, self.light_map(light)], dim=1))
        for block, skip in zip(self.decoder, reversed(skips)):
            x = block(x, skip)
        return torch.sigmoid(self.output(x))


def network_from_config(network: dict, device=None, where: str = "network") -> NeuralRenderer:
    """The network a run's config.json ``network`` section describes (on ``device``: "meta"
    allocates nothing); a run made before the additions has none of their keys. The section is
    untrusted: an addition's value outside what train writes is refused naming it (``where``)."""
    extra = network.get("extra_channels", 0)
    if extra not in EXTRA_CHANNEL_CHOICES or isinstance(extra, bool):
        raise FieldError(f"{where}.extra_channels", extra, " or ".join(map(str, EXTRA_CHANNEL_CHOICES)))
    code = network.get("environment_code", 0)
    if isinstance(code, bool) or not isinstance(code, int) or not 0 <= code <= MAX_CODE_SIZE:
        raise FieldError(f"{where}.environment_code", code, f"an integer from 0 to {MAX_CODE_SIZE}")
    environments = network.get("environments") or []
    if not isinstance(environments, list) or len(environments) > MAX_ENVIRONMENT_CODES:
        raise FieldError(
            f"{where}.environments", environments, f"a list of at most {MAX_ENVIRONMENT_CODES} map digests"
        )
    with torch.device(device) if device is not None else contextlib.nullcontext():
        return NeuralRenderer(
            network["resolution"],
            float(network.get("width", 1.0)),
            extra_channels=extra,
            environment_codes=len(environments),
            code_size=code,
        )


def parameter_count(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())
