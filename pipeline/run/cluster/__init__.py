"""Where a build's shards run: the one place that knows dask, split by concern.

``options`` (the cluster options of ``shaderball build``, checked before anything starts),
``connection`` (a local cluster, a scheduler or a dask-jobqueue cluster; the workers'
side; the build's task loop: :func:`pipeline.run.cluster.connection.run_shards_on_dask`),
``worker_env`` (the environment that steers the workers: render threads, GPU pins)
and ``watch`` (what a build waits on: batch jobs through ``squeue``, ``--start-timeout``).
"""
