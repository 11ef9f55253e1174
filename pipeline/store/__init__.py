"""Storage: the one place that knows the on-disk layout of a dataset.

Owns ``layout`` (paths of shards, records, maps, renders), ``folder`` (the one reader of
a dataset folder: record files, markers, the manifest, temporary files), ``exr`` (EXR
encoding with OpenEXR's layer naming), ``records`` (sample records, file entries, the
manifest lines), ``atomic`` (temp file, fsync, rename) and ``lock`` (one writer per folder). May import ``pipeline.errors`` only.
"""
