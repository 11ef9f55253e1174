"""Figures and tables in the docs, each reproducible with one command.

``shaderball figures sun-positions --out docs/img/sun_positions.png``;
``shaderball figures albedo-table``; ``shaderball figures contact-sheet --out PATH``;
``shaderball figures scenes --out docs/img/scenes.png`` (its maps: :mod:`pipeline.figures.environments`)
(``command``: the request, :class:`~pipeline.figures.command.FiguresRequest`).

Layer 8 of 10 in the layer contract (pyproject.toml, [tool.shaderball.layers]): may import
``pipeline``, ``materials``, ``sky``, ``geometry``, ``pipeline.image``, ``pipeline.errors``,
``pipeline.fields``, ``pipeline.store``, ``pipeline.render``, ``pipeline.dataset``,
``pipeline.check``, ``pipeline.study``, ``pipeline.run``, ``pipeline.publish``; nothing else
of the project.
"""
