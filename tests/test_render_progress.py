"""`shaderball render` says how far it is: the library hands each step to a callback (passes
done of total, samples per pixel, elapsed, ETA) and prints nothing itself; saying it changes
nothing of the render."""

from __future__ import annotations

import math

import numpy as np

from pipeline.render.command import RenderRequest, render_to_files
from pipeline.store.exr import read_exr
from support import VARIANT

KEYS = {"what", "done", "total", "spp_done", "spp", "elapsed_s", "eta_s"}


def _request(path, **changes) -> RenderRequest:
    return RenderRequest(out=str(path), settings={"resolution": 16, "spp": 7, "variant": VARIANT}, **changes)


def test_render_reports_each_pass_of_its_total_with_an_eta_and_prints_nothing(tmp_path, capfd):
    events = []
    request = _request(tmp_path / "said.exr")
    render_to_files(request, progress=events.append)
    printed = capfd.readouterr()
    assert printed.out == "" and printed.err == "", printed  # library code never prints

    from pipeline.render.renderer import sample_stages  # the passes render_sample renders

    passes = [n for stage in sample_stages(request.settings.resolved(VARIANT)) for n in stage]
    assert sum(passes) == request.settings.spp and len(passes) > 1  # 7 spp: passes of 4, 2 and 1 on llvm
    assert all(set(e) == KEYS and e["total"] == len(passes) and e["spp"] == request.settings.spp for e in events), (
        events
    )
    assert [e["done"] for e in events] == sorted(e["done"] for e in events)  # in order
    assert {e["done"] for e in events} == set(range(len(passes) + 1))  # every pass said, and the start
    for e in events:
        assert e["spp_done"] == sum(passes[: e["done"]]), e
        assert (e["eta_s"] is None) == (e["done"] == 0), e  # no ETA before a pass is timed
        assert e["eta_s"] is None or (math.isfinite(e["eta_s"]) and e["eta_s"] >= 0), e
    assert [e["elapsed_s"] for e in events] == sorted(e["elapsed_s"] for e in events)
    last = events[-1]
    assert last["done"] == len(passes) and last["eta_s"] == 0 and "writing" in last["what"], last

    quiet = _request(tmp_path / "quiet.exr")
    render_to_files(quiet)
    said, unsaid = read_exr(str(tmp_path / "said.exr")), read_exr(str(tmp_path / "quiet.exr"))
    for layer in unsaid.layers:
        assert np.array_equal(said.layers[layer], unsaid.layers[layer]), layer
