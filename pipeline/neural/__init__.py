"""The neural renderer stage: the network of "A Flexible Neural Renderer for Material
Visualization" (KT et al. 2019), its loss, tone map, metrics, training, inference and
evaluation over a dataset folder or its publication (docs/neural.md).

Importing this package does not import torch; its modules do.

Layer 8 of 10 in the layer contract (pyproject.toml, [tool.shaderball.layers]): may import
``materials``, ``sky``, ``geometry``, ``pipeline.errors``, ``pipeline.fields``,
``pipeline.image``, ``pipeline.store``, ``pipeline.render``, ``pipeline.check``,
``pipeline.publish``; nothing else of the project.
"""

import os

# torch's OpenMP threads spin at each barrier unless told otherwise; on a 2-core machine
# shared with other work (load 6-9) two spinning threads trained 2-7x slower than passive
# ones (`shaderball train --benchmark`, AVX2 kernels: 1.8-11 against 6.7-23 samples/s; 1
# thread: 4.8-14). libgomp reads this when torch loads, which every module here imports
# after this package; a setting of the user's own wins.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
