"""The neural renderer stage: the network of "A Flexible Neural Renderer for Material
Visualization" (KT et al. 2019), its loss, tone map, metrics, training, inference and
evaluation over a dataset folder or its publication (docs/neural.md).

Importing this package does not import torch; its modules do.

Layer 8 of 9 in the layer contract (pyproject.toml, [tool.shaderball.layers]): may import
``materials``, ``sky``, ``geometry``, ``pipeline.errors``, ``pipeline.fields``,
``pipeline.image``, ``pipeline.store``, ``pipeline.render``, ``pipeline.check``,
``pipeline.publish``; nothing else of the project.
"""
