"""The EXR format's choices a spec may name: the one list, read by the spec's check
(:mod:`pipeline.dataset.spec`, ``storage.compression``) and by the EXR writer
(:mod:`pipeline.store.exr`), neither of which may import the other."""

from __future__ import annotations

#: Lossless EXR compressions by the spec's name -> the ``OpenEXR`` module's constant.
EXR_COMPRESSIONS = {
    "none": "NO_COMPRESSION",
    "zip": "ZIP_COMPRESSION",
    "zips": "ZIPS_COMPRESSION",
    "piz": "PIZ_COMPRESSION",
    "rle": "RLE_COMPRESSION",
}
