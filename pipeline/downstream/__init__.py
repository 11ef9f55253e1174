"""What the network's accuracy costs in build time (`shaderball study --downstream`): the same
samples built at a ladder of spp, the same network trained on each, every network scored
against references of the held-out samples, and the cheapest level that is not worse.

Importing this package does not import torch; :mod:`pipeline.downstream.run` does.

Layer 9 of 10 in the layer contract (pyproject.toml, [tool.shaderball.layers]): may import
``pipeline.errors``, ``pipeline.fields``, ``pipeline.image``, ``pipeline.store``,
``pipeline.render``, ``pipeline.dataset``, ``pipeline.study``, ``pipeline.run``,
``pipeline.neural``; nothing else of the project.
"""
