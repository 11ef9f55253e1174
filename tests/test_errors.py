"""The error helpers every command's last line depends on."""

import pytest

from pipeline.errors import caused_by_interrupt


def test_an_interrupt_wrapped_by_a_library_is_still_an_interrupt():
    try:
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as inner:
            raise RuntimeError("drjit.custom(...): error while performing a custom operation") from inner
    except RuntimeError as exc:
        assert caused_by_interrupt(exc)
    assert not caused_by_interrupt(RuntimeError("a real failure"))
    assert caused_by_interrupt(KeyboardInterrupt())


def test_an_interrupt_in_a_plugin_mitsuba_loads_is_still_an_interrupt():
    """Mitsuba's scene parser gives a plugin constructor's KeyboardInterrupt back as a RuntimeError
    whose message holds the traceback (a Ctrl-C while a build moves to its next material)."""
    from pipeline.render.mitsuba_env import load_mitsuba

    mi = load_mitsuba("llvm_ad_rgb")

    def interrupted(props):
        raise KeyboardInterrupt

    mi.register_bsdf("shaderball_interrupted_test", interrupted)
    with pytest.raises(BaseException) as caught:
        mi.load_dict({"type": "shaderball_interrupted_test"})
    assert caused_by_interrupt(caught.value), repr(caught.value)
    assert not caused_by_interrupt(RuntimeError("Traceback ...\nValueError: a KeyboardInterrupt-free failure"))
