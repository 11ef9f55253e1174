"""The error helpers every command's last line depends on."""

import pytest

from pipeline.errors import USER_ERRORS, bad_value, caused_by_interrupt, check_int


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


def test_refused_integers_have_one_wording():
    with pytest.raises(USER_ERRORS, match=r"^--spp: 0 is not allowed; allowed: an integer from 1 to 9$"):
        check_int("--spp", 0, 1, 9)
    with pytest.raises(USER_ERRORS):
        check_int("--spp", True, 0, 9)  # a bool is not an integer here
    assert check_int("--spp", None, 1, 9) is None and check_int("--spp", 3, 1, 9) == 3
    assert str(bad_value("x", 1.5, "a whole number")) == "x: 1.5 is not allowed; allowed: a whole number"
