"""Measure how far mlcroissant's records of a publication's ``samples`` record set are from
``samples.jsonl`` read exactly (Python's ``json``): every float cell, relative difference.

    python scripts/croissant_floats.py PUB

Prints one JSON object: cells compared, cells that differ, the largest relative difference
and where (docs/publish.md, "Croissant").
"""

from __future__ import annotations

import json
import sys
import tarfile


def measure(pub: str) -> dict:
    import mlcroissant as mlc

    def no_extraction(*args, **kwargs):
        raise AssertionError("mlcroissant extracted an archive")

    tarfile.TarFile.extractall = no_extraction  # it never should: the record set reads no tar
    rows = [json.loads(line) for line in open(f"{pub}/samples.jsonl", encoding="utf-8")]
    records = list(mlc.Dataset(f"{pub}/croissant.json").records("samples"))
    cells = differ = 0
    worst = (0.0, None, None)

    def flat(record: dict, prefix: str = "samples/") -> dict:
        out = {}
        for key, value in record.items():
            if isinstance(value, dict):
                out.update(flat(value, key + "/"))
            else:
                out[key.rsplit("/", 1)[-1]] = value
        return out

    names = {"x": "sun_x", "y": "sun_y", "z": "sun_z"}
    for row, record in zip(rows, records, strict=True):
        got = flat(record)
        for key, value in got.items():
            column = key
            if key in names or key in ("r", "g", "b"):
                continue  # vector sub-fields: compared below by their column names
            if isinstance(row.get(column), float):
                cells += 1
                rel = abs(value - row[column]) / abs(row[column]) if row[column] else abs(value)
                differ += value != row[column]
                worst = max(worst, (rel, row["id"], column), key=lambda w: w[0])
        for vector, parts in (
            ("sun_direction", ("sun_x", "sun_y", "sun_z")),
            ("diffuse", ("diffuse_r", "diffuse_g", "diffuse_b")),
            ("specular", ("specular_r", "specular_g", "specular_b")),
            ("normal", ("normal_x", "normal_y", "normal_z")),
        ):
            sub = record[f"samples/{vector}"]
            for column in parts:
                axis = column.rsplit("_", 1)[1]
                value, exact = sub[f"samples/{vector}/{axis}"], row[column]
                if isinstance(exact, float):
                    cells += 1
                    differ += value != exact
                    rel = abs(value - exact) / abs(exact) if exact else abs(value)
                    worst = max(worst, (rel, row["id"], column), key=lambda w: w[0])
    return {
        "records": len(records),
        "float_cells": cells,
        "cells_differing": differ,
        "max_relative_difference": worst[0],
        "at": f"{worst[1]} {worst[2]}",
    }


if __name__ == "__main__":
    print(json.dumps(measure(sys.argv[1])))
