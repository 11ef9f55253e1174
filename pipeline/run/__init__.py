"""Running a build: the driver (``build``), the unit of work (``shard``) and where it runs (``cluster``).

``cluster`` is the only module that knows dask (local cluster, a scheduler, SLURM/PBS
through dask-jobqueue, worker recycling). ``shard`` renders one shard in this process;
``build`` plans, prepares the folder, runs the shards and writes the manifest; ``repair``
(``validate --repair``) deletes what validation finds bad and resumes the build. May import
``pipeline.check`` (the spec snapshot, validation for repair), ``pipeline.dataset``,
``pipeline.render``, ``pipeline.store``, ``pipeline.errors`` and the domain packages.
"""
