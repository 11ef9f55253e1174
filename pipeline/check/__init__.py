"""Checking a dataset folder: ``validate``, ``info``, ``preview``.

``validate`` is split by concern: ``report`` (problem kinds, report types, output),
``inspect`` (EXR and file checks), ``loading`` (the plan, manifest and markers read first),
``crosscheck`` (records against files and the plan, over ``discrepancies``: one record's),
``byshard`` (those checks one shard at a time over a compact index of the manifest);
``validate`` keeps the entry point. ``snapshot`` reads the spec a folder was built from.

Readers of a dataset, never writers: ``validate --repair`` re-renders, so it is a step of the
build (``pipeline.run.repair``). Never Mitsuba or dask.

Layer 6 of 10 in the layer contract (pyproject.toml, [tool.shaderball.layers]): may import
``pipeline.errors``, ``pipeline.fields``, ``pipeline.image``, ``pipeline.store``,
``pipeline.dataset``; nothing else of the project.
"""
