"""Pixels: the sRGB transfer function (``srgb``), the tone maps (``tonemap``: the network's
images and people's pictures), image metrics (``metrics``: PSNR, SSIM, relMSE, HDR-FLIP),
a render's statistics (``stats``), line charts as PNG (``chart``), denoising (``denoise``:
Intel Open Image Denoise) and the EXR format's choices (``formats``). Functions of arrays: no file, no renderer, no
dataset. Used by render, check, study, publish, neural and figures, so that none of them
reaches another for pixels.

Layer 1 of 10 in the layer contract (pyproject.toml, [tool.shaderball.layers]): imports
nothing of the project.
"""
