"""Figures and tables in the docs, each reproducible with one command.

``python -m pipeline.figures sun-positions --out docs/img/sun_positions.png``;
``python -m pipeline.figures.albedo_table``; ``python -m pipeline.figures.contact_sheet``.

Layer 8 of 9 in the layer contract (pyproject.toml, [tool.shaderball.layers]): may import
``pipeline``, ``materials``, ``sky``, ``geometry``, ``pipeline.image``, ``pipeline.errors``,
``pipeline.store``, ``pipeline.render``, ``pipeline.dataset``, ``pipeline.check``,
``pipeline.study``, ``pipeline.run``, ``pipeline.publish``; nothing else of the project.
"""
