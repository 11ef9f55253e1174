"""Writing the geometry cache: a temporary file in the same folder, then a rename.

The geometry cache is rebuilt when an entry is damaged (``geometry.shaderball``), so
a rename that never shows a torn file is all it needs; dataset files, which must
survive a crash, are written by ``pipeline.store.atomic`` (with fsync). Domain
packages import nothing of ``pipeline``, hence this small writer of its own.
"""

from __future__ import annotations

import os
import tempfile


def write_cache_file(path: str, data: bytes) -> None:
    folder = os.path.dirname(os.path.abspath(path))
    os.makedirs(folder, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix="-" + os.path.basename(path), dir=folder)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
