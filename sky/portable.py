"""sin and arcsin with the same bits on every machine, for the values a plan holds.

A plan must be a function of the spec alone (docs/spec.md, "The same plan on every
machine"). numpy's ``np.arcsin`` and libm's ``math.sin`` are not: their last bits depend
on the SIMD kernel numpy dispatches to (AVX-512 builds use other kernels than AVX2 ones)
and on libm's FMA variants, and a different last bit of one planned elevation changes
the plan digest (measured on an AMD AVX2 machine against an Intel AVX-512 one).

The functions here are built from the four operations and the square root only, each a
separate numpy ufunc (or Python float operation) in a fixed order. IEEE 754 rounds every
one of them correctly, numpy never fuses two ufunc calls into an FMA, and no reduction is
used (a pairwise sum's order depends on the SIMD width), so the result is bit-identical on
any IEEE machine, vectorised or scalar. Accuracy is a few ulp (tests/test_portable_math.py
measures it against numpy), which is all a sun angle needs; correct rounding is not the
point, sameness is.

Both functions take a numpy array or a Python float and return the same type;
:func:`asin_scalar` and :func:`sin_scalar` are the same arithmetic on Python floats with
``math.sqrt``, which the tests compare bit for bit with the numpy path.
"""

from __future__ import annotations

import math
from fractions import Fraction

import numpy as np

#: Degrees per radian and radians per degree, as Python computes them (an IEEE division).
DEG_PER_RAD = 180.0 / math.pi
RAD_PER_DEG = math.pi / 180.0
HALF_PI = math.pi / 2.0

# Taylor coefficients, each the correctly rounded double of an exact rational
# (Fraction -> float rounds once), so they are the same constants everywhere.
_SIN_TERMS = 13  # x^25 / 25! < 1e-17 of x on [0, pi/2]
_SIN_COEFFS = tuple(float(Fraction((-1) ** k, math.factorial(2 * k + 1))) for k in range(_SIN_TERMS))
_ATAN_TERMS = 15  # after two halvings |t| <= tan(pi/16): t^30 / 31 < 1e-22
_ATAN_COEFFS = tuple(float(Fraction((-1) ** k, 2 * k + 1)) for k in range(_ATAN_TERMS))


def _horner(x2, coeffs):
    """coeffs[0] + x2 * (coeffs[1] + x2 * (...)), innermost first: one fixed order."""
    acc = coeffs[-1]
    for c in reversed(coeffs[:-1]):
        acc = acc * x2 + c
    return acc


def _sin(x, sqrt):
    del sqrt  # sin needs none; the signature matches _asin's
    x2 = x * x
    return x * _horner(x2, _SIN_COEFFS)


def _asin(z, sqrt):
    # asin(z) = 2 atan(t), t = z / (1 + sqrt(1 - z^2)) in [-1, 1]; (1-z)(1+z) keeps 1 - z^2
    # accurate near |z| = 1. Two more half-angle steps, atan(t) = 2 atan(t / (1 + sqrt(1 + t^2))),
    # bring |t| below tan(pi/16), where the Taylor series converges fast.
    t = z / (1.0 + sqrt((1.0 - z) * (1.0 + z)))
    for _ in range(2):
        t = t / (1.0 + sqrt(1.0 + t * t))
    return 8.0 * (t * _horner(t * t, _ATAN_COEFFS))


def _check(values, lo: float, hi: float, what: str) -> None:
    arr = np.asarray(values, dtype=np.float64)
    if arr.size and not (np.all(arr >= lo) and np.all(arr <= hi)):
        raise ValueError(f"{what}: every value must lie in [{lo}, {hi}]")


def sin_rad(x):
    """sin(x) for x in [-pi/2, pi/2] (radians), the same bits on every machine."""
    _check(x, -HALF_PI, HALF_PI, "sin_rad")
    if isinstance(x, float):
        return sin_scalar(x)
    return _sin(np.asarray(x, dtype=np.float64), np.sqrt)


def asin_rad(z):
    """arcsin(z) in radians for z in [-1, 1], the same bits on every machine."""
    _check(z, -1.0, 1.0, "asin_rad")
    if isinstance(z, float):
        return asin_scalar(z)
    return _asin(np.asarray(z, dtype=np.float64), np.sqrt)


def sin_scalar(x: float) -> float:
    """:func:`sin_rad` on one Python float, without numpy."""
    return float(_sin(float(x), math.sqrt))


def asin_scalar(z: float) -> float:
    """:func:`asin_rad` on one Python float, without numpy."""
    return float(_asin(float(z), math.sqrt))


def sin_deg(degrees):
    """sin of an angle in degrees in [-90, 90]: :func:`sin_rad` of ``degrees * RAD_PER_DEG``."""
    if isinstance(degrees, float | int):
        return sin_rad(float(degrees) * RAD_PER_DEG)
    return sin_rad(np.asarray(degrees, dtype=np.float64) * RAD_PER_DEG)


def asin_deg(z):
    """arcsin(z) in degrees: :func:`asin_rad` times :data:`DEG_PER_RAD`."""
    return asin_rad(z) * DEG_PER_RAD
