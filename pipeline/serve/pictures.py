"""The pictures the server sends: PNG data URLs of HDR frames and maps, the network-vs-path
difference, and the path-traced frame's own noise (pure numpy; no Mitsuba, no torch)."""

from __future__ import annotations

import base64
import io
import math

import numpy as np

from pipeline.image.metrics import psnr8
from pipeline.image.tonemap import hdr_to_srgb8, map_srgb8, tonemap
from pipeline.render.raster import encode_normal_texture
from pipeline.render.renderer import luminance_variance

#: The difference image is scaled by this before display (errors are small).
DIFF_GAIN = 4.0


def png_data_url(pixels: np.ndarray) -> str:
    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(pixels)).save(buffer, format="PNG", compress_level=1)
    return "data:image/png;base64," + base64.b64encode(buffer.getvalue()).decode("ascii")


def box_down(image: np.ndarray, factor: int) -> np.ndarray:
    if factor == 1:
        return image
    h, w = image.shape[:2]
    return image.reshape(h // factor, factor, w // factor, factor, -1).mean(axis=(1, 3)).astype(np.float32)


def maps_strip(screen: dict[str, np.ndarray]) -> np.ndarray:
    """The four screen-space maps side by side as one 8-bit picture (albedos sRGB-encoded)."""
    rough = np.repeat(screen["roughness"][..., None], 3, axis=2)
    normal = encode_normal_texture(screen["normal"]) * screen["mask"][..., None]
    tiles = [map_srgb8(screen["diffuse"]), map_srgb8(screen["specular"]), map_srgb8(rough, False)]
    return np.concatenate(tiles + [map_srgb8(normal, False)], axis=1)


def texture_srgb8(name: str, texels: np.ndarray) -> np.ndarray:
    """A decoded upload (texture space, as :func:`pipeline.serve.materials.decode_upload` gives
    it) as the page's paint canvas shows it: albedos sRGB-encoded, roughness grey, normals in
    the (n + 1) / 2 encoding."""
    if name == "normal":
        return map_srgb8(encode_normal_texture(texels), False)
    if name == "roughness":
        return map_srgb8(np.repeat(texels[..., :1], 3, axis=2), False)
    return map_srgb8(texels[..., :3])


def unbiased_variance(out: np.ndarray, spp: int) -> np.ndarray | None:
    """The variance of each pixel's luminance estimate from ``spp`` samples, or None when it
    cannot be measured. The moment integrator gives the samples' second moment; m2 - m1^2 is
    their variance with 1/spp weights (biased low by (spp - 1)/spp), and with one sample per
    pixel (a box filter) it is 0 whatever the noise: the first pass's noise is unknown."""
    if spp < 2:
        return None
    return (luminance_variance(out, spp) * (spp / (spp - 1))).astype(np.float32)


def noise_psnr_db(path_hdr: np.ndarray, variance: np.ndarray | None, factor: int, exposure: float) -> float | None:
    """The path-traced frame's own noise as a PSNR against its converged limit, in the displayed
    8-bit space at the network's resolution: each pixel moved by one standard deviation of its
    estimate (the luminance variance of :func:`unbiased_variance`, over ``factor``^2 pixels
    averaged), through the tone map (first order). None where the variance is not known (one
    sample per pixel): a noisy frame is never reported as noiseless."""
    if variance is None:
        return None
    mean = box_down(path_hdr, factor)
    sigma = np.sqrt(box_down(variance[..., None], factor) / (factor * factor))
    delta = (tonemap(mean + sigma, exposure) - tonemap(mean, exposure)) * 255.0
    mse = float(np.mean(delta.astype(np.float64) ** 2))
    return math.inf if mse == 0 else 10.0 * math.log10(255.0**2 / mse)


def difference(network_hdr: np.ndarray, path_hdr: np.ndarray, variance: np.ndarray | None, exposure: float) -> dict:
    """|network - path| of the displayed 8-bit pictures (at the network's resolution, the path
    frame box-averaged to it), the PSNR between them, and the path frame's own noise as a PSNR
    (None while it is unknown)."""
    factor = path_hdr.shape[0] // network_hdr.shape[0]
    reference = hdr_to_srgb8(box_down(path_hdr, factor), exposure)
    test = hdr_to_srgb8(network_hdr, exposure)
    delta = np.abs(test.astype(np.int16) - reference.astype(np.int16)).astype(np.float32) * DIFF_GAIN
    noise = noise_psnr_db(path_hdr, variance, factor, exposure)
    return {
        "png": png_data_url(np.clip(delta, 0, 255).astype(np.uint8)),
        "psnr_db": round(psnr8(test, reference), 2),
        "noise_psnr_db": None if noise is None else round(noise, 2),
        "gain": DIFF_GAIN,
    }
