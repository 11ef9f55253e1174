"""The server's scheduling and checks without Mitsuba or HTTP: latest-wins slots, generations
that drop stale results, the view parser, the upload decoder's bounds."""

from __future__ import annotations

import io
import threading

import numpy as np
import pytest
from PIL import Image

from pipeline.fields import FieldError
from pipeline.serve.materials import MAX_UPLOAD_BYTES, TEXTURE_TEXELS, decode_upload, maps_from_uploads
from pipeline.serve.view import RequestError, UniformChoice, View, api_error, api_status, parse_view
from pipeline.serve.workers import Hub, Job, LatestSlots
from sky import Light

VIEW = View(UniformChoice((0.5, 0.5, 0.5), 0.04, 0.3, False, 0.0), Light(45.0, 270.0, 3.0), 4.0)


def _job(client: str, generation: int) -> Job:
    return Job(client, generation, VIEW, maps=None)


def test_a_slot_keeps_only_the_latest_job_of_a_client_and_clients_take_turns():
    slots = LatestSlots()
    for generation in range(1, 6):
        slots.put(_job("a", generation))
    slots.put(_job("b", 1))
    slots.put(_job("a", 9), replace=False)  # a pass going on does not displace a newer view
    assert (slots.take().client, slots.take().client) == ("a", "b")
    assert not slots.jobs
    slots.put(_job("a", 7))
    slots.put(_job("b", 2))
    slots.put(_job("a", 8))  # replaced: goes behind b
    assert [slots.take().generation for _ in range(2)] == [2, 8]


def test_a_closed_slot_wakes_its_taker():
    slots, got = LatestSlots(), []
    taker = threading.Thread(target=lambda: got.append(slots.take()))
    taker.start()
    slots.close()
    taker.join(10)
    assert got == [None]


def test_a_result_of_an_older_generation_is_dropped():
    hub = Hub(path_resolution=128, network_resolution=None)
    first = hub.submit("tab", VIEW, lambda: "maps")
    second = hub.submit("tab", VIEW, lambda: pytest.fail("same material: its maps are kept"))
    assert second == first + 1
    assert hub.publish(_job("tab", first), "path", {"spp": 1}) is False
    assert "path" not in hub.frame("tab", 0, 0.0)
    assert hub.publish(_job("tab", second), "path", {"spp": 1}) is True
    frame = hub.frame("tab", 0, 0.0)
    assert frame["path"] == {"spp": 1} and frame["generation"] == second
    assert [job.generation for job in hub.path_slots.jobs.values()] == [second]


def test_a_refused_material_leaves_the_client_as_it_was():
    hub = Hub(path_resolution=128, network_resolution=None)
    generation = hub.submit("tab", VIEW, lambda: "maps")

    def refuse():
        raise RequestError("material.sample: no", 404)

    other = View(UniformChoice((0.1, 0.1, 0.1), 0.04, 0.3, False, 0.0), VIEW.light, 4.0)
    with pytest.raises(RequestError):
        hub.submit("tab", other, refuse)
    assert hub.frame("tab", 0, 0.0)["generation"] == generation


def test_a_view_parses_and_its_fields_are_checked_by_name():
    client, view = parse_view(
        {
            "client": "tab-1",
            "material": {"kind": "svbrdf", "family": "tiles", "seed": 7},
            "light": {"elevation_deg": 30, "azimuth_deg": 90, "turbidity": 2},
            "exposure": 2,
        }
    )
    assert client == "tab-1" and view.material.family == "tiles" and view.light.turbidity == 2.0
    # The library names the field by its own name; the server words it as the JSON spells it.
    with pytest.raises(FieldError, match=r"^elevation_deg: nan is not allowed") as refused:
        parse_view({"client": "x", "material": {"kind": "uniform"}, "light": {"elevation_deg": float("nan")}})
    assert str(api_error(refused.value)).startswith("light.elevation_deg: nan is not allowed; a finite number")
    with pytest.raises(FieldError) as refused:
        parse_view({"client": "x", "material": {"kind": "uniform", "metal": "yes"}, "light": {}})
    assert str(api_error(refused.value)) == 'material.metal: "yes" is not allowed; true or false'
    assert api_status(refused.value) == 400


def _png(size, mode="RGB", colour=(10, 20, 30)) -> bytes:
    buffer = io.BytesIO()
    Image.new(mode, size, colour).save(buffer, format="PNG")
    return buffer.getvalue()


def test_uploads_are_resampled_to_texture_maps_and_bounded():
    diffuse = decode_upload("diffuse", _png((3, 5), colour=(255, 0, 51)))
    assert diffuse.shape == (TEXTURE_TEXELS, TEXTURE_TEXELS, 3)
    assert np.allclose(diffuse[0, 0], [1.0, 0.0, 0.2], atol=1e-6)
    rough = decode_upload("roughness", _png((8, 8), mode="L", colour=128))
    normal = decode_upload("normal", _png((8, 8), colour=(128, 128, 255)))
    assert np.allclose(np.linalg.norm(normal, axis=-1), 1.0, atol=1e-5)
    maps = maps_from_uploads({"diffuse": diffuse, "roughness": rough, "normal": normal})
    maps.check()
    assert maps.resolution == (TEXTURE_TEXELS, TEXTURE_TEXELS)
    with pytest.raises(FieldError) as refused:
        decode_upload("diffuse", b"\x89PNG\r\n\x1a\n" + b"\0" * (MAX_UPLOAD_BYTES))
    assert api_status(refused.value) == 413 and "is not allowed; at most" in str(refused.value)
    with pytest.raises(FieldError) as refused:
        decode_upload("albedo", _png((2, 2)))
    assert api_status(refused.value) == 404 and str(api_error(refused.value)).startswith('map: "albedo"')


def test_the_noise_psnr_estimate_matches_the_psnr_of_real_noise():
    """Frames of a known per-pixel variance: the estimate is within 1 dB of the PSNR their
    noise actually costs through the tone map (not rounded to 8 bits, which would floor it)."""
    from pipeline.image.tonemap import tonemap
    from pipeline.serve.workers import noise_psnr_db

    rng = np.random.default_rng(5)
    clean = rng.uniform(0.01, 0.3, size=(64, 64, 1)).astype(np.float32).repeat(3, axis=2)
    variance = (0.004 * clean[..., 0]) ** 2
    estimate = noise_psnr_db(clean, variance, 1, 4.0)
    errors = []
    for _ in range(20):
        noisy = clean + rng.standard_normal((64, 64, 1)).astype(np.float32) * np.sqrt(variance)[..., None]
        errors.append(np.mean(((tonemap(noisy, 4.0) - tonemap(clean, 4.0)) * 255.0) ** 2))
    measured = 10 * np.log10(255.0**2 / np.mean(errors))
    assert abs(estimate - measured) < 1.0, (estimate, measured)
    assert noise_psnr_db(clean, variance, 2, 4.0) > estimate + 4  # 4 pixels averaged: about 6 dB less noise


def test_the_decode_budget_makes_a_decode_wait_for_room_and_refuses_one_that_waits_too_long():
    from pipeline.serve.materials import DecodeBudget

    budget, order = DecodeBudget(100), []
    with budget.reserve(80, "first"):
        with pytest.raises(RequestError) as refused:
            with budget.reserve(50, "second", wait_s=0.05):
                pass
        assert refused.value.status == 503 and "second" in str(refused.value)
        waiter = threading.Thread(target=lambda: _hold(budget, 50, order))
        waiter.start()
        waiter.join(0.2)
        assert order == []  # no room yet: 80 + 50 > 100
    waiter.join(60)
    assert order == ["decoded"] and budget.used == 0
    with budget.reserve(10**12, "huge", wait_s=0.05):  # past the whole budget: alone, not never
        assert budget.used == 100


def _hold(budget, nbytes: int, order: list) -> None:
    with budget.reserve(nbytes, "waiter", wait_s=60):
        order.append("decoded")


def test_a_16_bit_upload_is_decoded_to_its_value_at_the_texture_size():
    buffer = io.BytesIO()
    Image.fromarray(np.full((300, 200), 40000, np.uint16)).save(buffer, format="PNG")
    pixels = decode_upload("diffuse", buffer.getvalue())
    assert pixels.shape == (TEXTURE_TEXELS, TEXTURE_TEXELS, 3) and pixels.dtype == np.float32
    assert np.allclose(pixels, 40000 / 65535, atol=1e-5)


def test_the_uploads_of_all_clients_together_are_bounded(monkeypatch):
    import pipeline.serve.workers as workers

    hub = Hub(path_resolution=16, network_resolution=None)
    texels = np.zeros((256, 256, 3), np.float32)
    monkeypatch.setattr(workers, "MAX_STORED_UPLOAD_BYTES", 2 * texels.nbytes)
    hub.store_upload("a", "diffuse", texels)
    hub.store_upload("b", "diffuse", texels)
    hub.store_upload("b", "diffuse", texels)  # replacing a map takes no more room
    with pytest.raises(RequestError) as refused:
        hub.store_upload("c", "diffuse", texels)
    assert refused.value.status == 503 and "uploads" in str(refused.value)
