"""Running a build: the driver (``build``), the unit of work (``shard``) and where it runs (``cluster``).

``cluster`` is the only place that knows dask, split by concern: ``options`` (checked),
``connection`` (local cluster, a scheduler, SLURM/PBS through dask-jobqueue, worker
recycling, the task loop) and ``watch`` (batch jobs, ``--start-timeout``). ``shard``
renders one shard in this process; ``build`` plans, prepares the folder, runs the shards
and writes the manifest; ``repair`` (``validate --repair``) deletes what validation finds
bad and resumes the build. It stands
above ``pipeline.check``: a resumed build reads the spec snapshot, and a repair validates.

Layer 7 of 10 in the layer contract (pyproject.toml, [tool.shaderball.layers]): may import
``pipeline``, ``materials``, ``sky``, ``geometry``, ``pipeline.errors``,
``pipeline.fields``, ``pipeline.store``, ``pipeline.render``, ``pipeline.dataset``,
``pipeline.check``; nothing else of the project.
"""
