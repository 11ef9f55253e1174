"""Storage: the one place that knows the on-disk layout of a dataset.

Owns ``layout`` (paths of shards, records, maps, renders), ``folder`` (the one reader of
a dataset folder: record files, markers, the manifest, temporary files), ``exr`` (EXR
encoding with OpenEXR's layer naming), ``exrheader`` (an EXR's header checked against what
is expected of the file before any pixel is decoded), ``records`` (sample records, file entries, the
manifest lines), ``atomic`` (temp file, fsync, rename: the one atomic writer), ``links`` (no
write through a symbolic link inside a run or dataset folder) and ``lock`` (one writer per folder).

Layer 3 of 10 in the layer contract (pyproject.toml, [tool.shaderball.layers]): may import
``pipeline.errors``, ``pipeline.image``; nothing else of the project.
"""
