"""What the ``shaderball`` command shows and reads: progress lines on stderr
(:mod:`pipeline.ui.progress`), option values that need parsing (:mod:`pipeline.ui.values`),
and click options generated from typed fields (:mod:`pipeline.ui.options`: a parameter is
declared once, in the dataclass that owns it). The command (``cli.py``) uses it; library code
never does, since library code never prints.

Layer 4 of 9 in the layer contract (pyproject.toml, [tool.shaderball.layers]): may import
``pipeline.errors``, ``pipeline.fields``; nothing else of the project.
"""
