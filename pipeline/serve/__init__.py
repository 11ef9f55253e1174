"""`shaderball serve`: the paper's material tool as a local web page, with path-traced ground
truth beside the network (docs/serve.md).

The standard library's HTTP server, one static page in this package, a small JSON API; one
thread for Mitsuba, one for the network. The network is handed in (pipeline.neural.live), so
this package never imports torch and serves a path-traced previewer without one.

Layer 8 of 10 in the layer contract (pyproject.toml, [tool.shaderball.layers]): may import
``materials``, ``sky``, ``geometry``, ``pipeline.errors``, ``pipeline.fields``,
``pipeline.image``, ``pipeline.store``, ``pipeline.render``, ``pipeline.dataset``,
``pipeline.publish.names``, ``pipeline.ui.interrupt``; nothing else of the project.
"""
