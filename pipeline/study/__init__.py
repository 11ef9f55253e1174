"""The accuracy study: what accuracy costs in time (``shaderball study``, docs/accuracy.md).

Owns the choice of study samples from a spec's own plan (``select``), the configurations
varied from the spec's recipe (``configs``), the error metrics against per-sample
references and the reference's error floor (``measure``), denoising with Intel Open Image
Denoise and its guide buffers (``denoise``), the run with its repeats, resume and
progress (``run``), paired ratios with bootstrap intervals and the rule that lets one
recipe replace another (``stats``), and the tables, plot and recommended recipes
(``report``).

Mitsuba is used only through ``pipeline.render`` (the variant is resolved once, at the
study's edge); its LDR metrics are those of the images the network is trained on
(``pipeline.image``). Never dask, ``pipeline.run``, ``pipeline.check`` or ``pipeline.neural``.

Layer 6 of 10 in the layer contract (pyproject.toml, [tool.shaderball.layers]): may import
``materials``, ``sky``, ``geometry``, ``pipeline.errors``, ``pipeline.fields``,
``pipeline.image``, ``pipeline.store``, ``pipeline.render``, ``pipeline.dataset``; nothing
else of the project.
"""
