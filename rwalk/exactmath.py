"""sin, cos, atan, atan2, asin and acos that round the same on every CPU and batch size.

torch's (and numpy's) vectorised transcendental kernels take different code
paths by tensor length and by the CPU's vector instruction set (SSE, AVX2,
AVX-512), so the last bit of ``torch.atan2`` can depend on how many envs share
a batch and on which machine runs it. IEEE-754, however, rounds +, -, x, / and
sqrt correctly, element by element, identically in SIMD and scalar code. So
every function here is built from those alone (plus floor, abs, comparisons,
``where``, ``copysign`` and table look-ups, which are exact), one operation per
call, in float64: range reduction, then a polynomial evaluated by Horner's rule
in separate multiply and add calls (never a fused op that a kernel may compile
to an FMA: no ``addcmul``, ``lerp``, ``alpha=``, matmul or reductions). The
result is a pure function of the input bits. One exception to the premise:
``torch.sqrt`` of float64 on the CPU goes through MKL's vector math and rounds
~1% of results the other way, so sqrt is numpy's (``rwalk.arrayops``).

atan2 (and atan, asin, acos) take torch tensors, numpy arrays or Python floats
and run the same operations on each, so all three give the same bits: the
batched core uses tensors, the single env arrays and floats (``rwalk.single``).

Accuracy (tests/test_exact.py checks it against torch on random and edge-case
inputs, and against mpmath): within 2 ulp of the exact value and 3e-16 absolute
(at most 1.3 ulp for |x| <= π/4, where sin x needs no reduction); sin and cos
are covered for |x| <= ``SIN_COS_LIMIT`` (2^20 π/2, about 1.6e6 rad; near
their zeros only the absolute error is small) and give NaN beyond it.

Covered: these functions and everything in rwalk built on them (gait tables,
IK, observation, reward and termination, start poses), on any x86-64 CPU in
torch's eager mode. Not covered: MuJoCo's own C code. Each simulation is
deterministic and independent of the batch it runs in, but MuJoCo uses libm
and may be compiled with FMA contraction and SIMD paths of its own, so the
physics on a different CPU or MuJoCo build can differ in the last bit, which
we cannot control from here. ``torch.compile`` may fuse operations (into FMAs)
and is not covered either.

Constants were computed once with mpmath at 300 bits and pasted as hex
literals (see each); the Taylor coefficients 1/n! and 1/n are Python's
correctly rounded integer divisions, the same everywhere.
"""

from __future__ import annotations

import math

from rwalk import arrayops
from rwalk.arrayops import Tensor

#: Largest |x| for which sin and cos are accurate; beyond it they return NaN.
SIN_COS_LIMIT = math.ldexp(1.0, 20) * 1.5707963267948966

# π/2 in three parts (mpmath): C1 and C2 have 33 significant bits, so k * C1 and
# k * C2 are exact for |k| < 2^20 (Cody-Waite reduction); C3 is the rest.
_PIO2_C1 = float.fromhex("0x1.921fb54400000p+0")
_PIO2_C2 = float.fromhex("0x1.0b4611a600000p-34")
_PIO2_C3 = float.fromhex("0x1.3198a2e037073p-69")
_TWO_OVER_PI = float.fromhex("0x1.45f306dc9c883p-1")
# π and π/2 as double + remainder (mpmath).
_PI_HI = float.fromhex("0x1.921fb54442d18p+1")
_PI_LO = float.fromhex("0x1.1a62633145c07p-53")
_PIO2_HI = float.fromhex("0x1.921fb54442d18p+0")
_PIO2_LO = float.fromhex("0x1.1a62633145c07p-54")
# atan(j/8), j = 0..8, as double + remainder (mpmath.atan at 300 bits).
_ATAN_HI = tuple(
    float.fromhex(h)
    for h in (
        "0x0.0p+0",
        "0x1.fd5ba9aac2f6ep-4",
        "0x1.f5b75f92c80ddp-3",
        "0x1.6f61941e4def1p-2",
        "0x1.dac670561bb4fp-2",
        "0x1.1e00babdefeb4p-1",
        "0x1.4978fa3269ee1p-1",
        "0x1.700a7c5784634p-1",
        "0x1.921fb54442d18p-1",
    )
)
_ATAN_LO = tuple(
    float.fromhex(h)
    for h in (
        "0x0.0p+0",
        "-0x1.cd37686760c17p-59",
        "0x1.8ab6e3cf7afbdp-57",
        "-0x1.c63aae6f6e918p-56",
        "0x1.a2b7f222f65e2p-56",
        "-0x1.928df287a668fp-58",
        "0x1.2419a87f2a458p-56",
        "-0x1.8c34d25aadef6p-56",
        "0x1.1a62633145c07p-55",
    )
)
# Taylor coefficients in s = r²: sin r = r + r s (-1/3! + s/5! - ... + s^7/17!) and
# cos r = 1 + s (-1/2! + s/4! - ... + s^7/16!); on |r| <= π/4 the first omitted term
# is below 1e-18. atan t = t + t s (-1/3 + s/5 - ... + s^5/13) on |t| <= 1/16
# (first omitted term below 1e-18 relative).
_SIN = tuple((-1) ** (k + 1) / math.factorial(2 * k + 3) for k in range(8))
_COS = tuple((-1) ** (k + 1) / math.factorial(2 * k + 2) for k in range(8))
_ATAN = tuple((-1) ** (k + 1) / (2 * k + 3) for k in range(6))

#: Smallest positive double (denominator floor: 0/0 becomes 0/_TINY = 0).
_TINY = 5e-324


def _two_sum(a: float, b: float) -> tuple[float, float]:
    """a + b as a double and its exact rounding error (Knuth's TwoSum, IEEE doubles)."""
    total = a + b
    b_part = total - a
    return total, (a - (total - b_part)) + (b - b_part)


def _octant_tables() -> tuple[tuple[float, ...], tuple[float, ...], tuple[float, ...]]:
    """base + sign x atan(j/8) as (hi, lo) and the sign, for octant code 0..3 and j = 0..8.

    atan2 = base + sign (atan(j/8) + atan t): code = 2 swap + (x < 0), where swap means
    |y| > |x|. Codes: 0 -> 0 + v, 1 -> π - v, 2 -> π/2 - v, 3 -> π/2 + v.
    """
    bases = ((0.0, 0.0, 1.0), (_PI_HI, _PI_LO, -1.0), (_PIO2_HI, _PIO2_LO, -1.0))
    bases += ((_PIO2_HI, _PIO2_LO, 1.0),)
    hi, lo, sign = [], [], []
    for base_hi, base_lo, sgn in bases:
        for atan_hi, atan_lo in zip(_ATAN_HI, _ATAN_LO, strict=True):
            total, error = _two_sum(base_hi, sgn * atan_hi)
            hi.append(total)
            lo.append(error + (base_lo + sgn * atan_lo))
            sign.append(sgn)
    return tuple(hi), tuple(lo), tuple(sign)


_OCTANT_HI, _OCTANT_LO, _OCTANT_SIGN = _octant_tables()


#: Per octant code and j: (sign, lo, hi) of base + sign x atan(j/8).
_OCTANT = arrayops.Table(tuple(zip(_OCTANT_SIGN, _OCTANT_LO, _OCTANT_HI, strict=True)))


def _as_f64(x):
    """x as float64 in its own kind of array (a float or a tuple: a numpy array)."""
    xp = arrayops.of(x)
    if xp is arrayops.FloatOps:
        xp = arrayops.NumpyOps
    return xp, xp.as_f64(x)


def _horner(s, coeffs: tuple[float, ...]):
    """c0 + s (c1 + s (c2 + ...)), one multiply and one add per call (no FMA)."""
    acc = s * coeffs[-1]
    for k in range(len(coeffs) - 2, -1, -1):
        acc += coeffs[k]  # in place on tensors and arrays
        if k:
            acc *= s
    return acc


def _sin_cos(x: Tensor) -> tuple[Tensor, Tensor]:
    xp, x = _as_f64(x)
    # Reduce: x = k π/2 + r, |r| <= π/4 (a hair more where x * 2/π rounds up).
    k = xp.floor(x * _TWO_OVER_PI + 0.5)
    r = x - k * _PIO2_C1
    r = r - k * _PIO2_C2
    r = r - k * _PIO2_C3
    quadrant = k - xp.floor(k * 0.25) * 4.0  # k mod 4, exact
    s = r * r
    sin_r = r * s
    sin_r = sin_r * _horner(s, _SIN)
    sin_r = r + sin_r
    sin_r = xp.where(r == 0, r, sin_r)  # keep the sign of zero
    cos_r = s * _horner(s, _COS)
    cos_r = cos_r + 1.0
    odd = (quadrant == 1.0) | (quadrant == 3.0)
    sin = xp.where(odd, cos_r, sin_r)
    cos = xp.where(odd, sin_r, cos_r)
    sin = xp.where(quadrant >= 2.0, -sin, sin)
    cos = xp.where((quadrant == 1.0) | (quadrant == 2.0), -cos, cos)
    outside = ~(abs(x) <= SIN_COS_LIMIT)  # also NaN and ±inf
    sin = xp.where(outside, math.nan, sin)
    cos = xp.where(outside, math.nan, cos)
    return sin, cos


def sin(x):
    """sin x of a tensor or a numpy array (the same bits), float64, same shape; NaN where
    |x| > SIN_COS_LIMIT or x is not finite."""
    return _sin_cos(x)[0]


def cos(x):
    """cos x of a tensor or a numpy array (the same bits), float64, same shape; NaN where
    |x| > SIN_COS_LIMIT or x is not finite."""
    return _sin_cos(x)[1]


def atan2(y, x):
    """The angle of (x, y) in [-π, π], as ``torch.atan2`` (signed zeros and infinities
    included). Inputs broadcast; float64 result.

    Takes torch tensors, numpy arrays or floats (a tuple of floats elementwise), with
    the same operations and so the same bits for each (see ``rwalk.arrayops``).

    With a = min(|x|, |y|) / max(|x|, |y|) in [0, 1] and j = round(8a), the angle is
    base + sign (atan(j/8) + atan t), t = (a - j/8) / (1 + a j/8), |t| <= 1/16; base,
    sign and atan(j/8) come from one table lookup. Few ``where`` calls: they are
    several times slower than arithmetic on large tensors.
    """
    if type(y) is tuple:
        return tuple(atan2(a, b) for a, b in zip(y, x, strict=True))
    xp = arrayops.of(y, x)
    y, x = xp.as_f64(y), xp.as_f64(x)
    if xp is not arrayops.FloatOps and y.shape != x.shape:
        y, x = xp.broadcast(y, x)
    # Augmented assignments work in place on tensors and arrays (no temporaries of the
    # batch's size) and rebind floats.
    ax, ay = abs(x), abs(y)
    den = xp.clamp(xp.maximum(ax, ay), _TINY)  # 0/0 -> 0
    a = xp.minimum(ax, ay)
    a /= den
    a = xp.nan_to(a, 1.0)  # inf/inf -> 1 (a NaN input is restored below)
    j = a * 8.0
    j += 0.5
    j = xp.floor(j)
    c = j * 0.125
    t = a - c
    c *= a
    c += 1.0
    t /= c
    s = t * t
    p = _horner(s, _ATAN)
    p *= s
    p *= t
    p += t  # atan t = t + t s P(s), |t| <= 1/16
    # Table index: 9 (2 swap + (x < 0)) + j.
    code = xp.as_float(ay > ax) * 2.0
    code += xp.as_float(xp.signbit(x))
    code *= 9.0
    code += j
    sign, lo, hi = xp.lookup(_OCTANT, code)
    angle = sign * p
    angle += lo
    angle += hi
    # NaN in -> NaN out: ax + ay is NaN only then (both >= 0), so this adds 0 or NaN.
    ax += ay
    angle += xp.clamp(ax, None, 0.0)
    return xp.copysign(angle, y)


def atan(x):
    """atan x in [-π/2, π/2], float64, same shape (tensor, array or float)."""
    return atan2(arrayops.of(x).as_f64(x), 1.0)


def _cosine_of_asin(x):
    """sqrt(1 - x²) computed as sqrt((1 - x)(1 + x)), exact factors near |x| = 1."""
    one_minus = 1.0 - x
    one_plus = 1.0 + x
    return arrayops.of(x).sqrt(one_minus * one_plus)


def asin(x):
    """asin x in [-π/2, π/2], float64, same shape; NaN outside [-1, 1]."""
    x = arrayops.of(x).as_f64(x)
    return atan2(x, _cosine_of_asin(x))


def acos(x):
    """acos x in [0, π], float64, same shape; NaN outside [-1, 1]."""
    x = arrayops.of(x).as_f64(x)
    return atan2(_cosine_of_asin(x), x)
