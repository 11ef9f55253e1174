"""The accuracy study: what accuracy costs in time (``shaderball study``, docs/accuracy.md).

Owns the choice of study samples from a spec's own plan (``select``), the configurations
varied from the spec's recipe (``configs``), the error metrics against per-sample
references and the reference's error floor (``measure``), denoising with Intel Open Image
Denoise and its guide buffers (``denoise``), the run with its repeats, resume and
progress (``run``), paired ratios with bootstrap intervals and the rule that lets one
recipe replace another (``stats``), and the tables, plot and recommended recipes
(``report``).

May import the domain packages (materials, sky, geometry), ``pipeline.errors``,
``pipeline.dataset`` (spec, plan, materials), ``pipeline.render`` (the renderer, through
which alone Mitsuba is used; the variant is resolved once, at the study's edge),
``pipeline.store`` (atomic writes, EXR) and the neural stage's tone map and image metrics
(``pipeline.neural.tonemap``, ``pipeline.neural.metrics``: the study's LDR metrics are
those of the images the network is trained on). Never dask, ``pipeline.run`` or
``pipeline.check``.
"""
