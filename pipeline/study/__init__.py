"""The accuracy study: what accuracy costs in time (``shaderball study``, docs/accuracy.md).

Owns the choice of study samples from a spec's own plan (``select``), the configurations
varied from the spec's recipe (``configs``), the error metrics against per-sample
references and the reference's error floor (``measure``), denoising with Intel Open Image
Denoise and its guide buffers (``denoise``), the run with its resume and progress
(``run``), and the tables, Pareto plot and recommended recipes (``report``).

May import the domain packages (materials, sky, geometry), ``pipeline.errors``,
``pipeline.dataset`` (spec, plan, materials), ``pipeline.render`` (the renderer, through
which alone Mitsuba is used; the variant is resolved once, at the study's edge),
``pipeline.store`` (atomic writes, EXR) and ``pipeline.image`` (the tone map and image
metrics of the images the network is trained on, OIDN). Never dask, ``pipeline.run``,
``pipeline.check`` or ``pipeline.neural``.
"""
