"""What the ``shaderball`` command shows and how it runs: progress lines on stderr
(:mod:`pipeline.ui.progress`), commands generated from the library's checked requests
(:mod:`pipeline.ui.command`, over :mod:`pipeline.ui.options`: a parameter is declared once, in
the dataclass that owns it), and the process around a command: exit codes, --json's one
document, Ctrl-C (:mod:`pipeline.ui.process`). The command (``cli.py``) uses it; library code
never does, since library code never prints.

Layer 4 of 10 in the layer contract (pyproject.toml, [tool.shaderball.layers]): may import
``pipeline.errors``, ``pipeline.fields``; nothing else of the project.
"""
