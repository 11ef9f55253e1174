"""Shared fixtures. Mitsuba is loaded through pipeline.mitsuba_env so libLLVM is selected first."""

import pytest


@pytest.fixture(scope="session")
def mi():
    from pipeline.mitsuba_env import load_mitsuba

    return load_mitsuba("llvm_ad_rgb")
