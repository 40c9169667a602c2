"""Scientific-notation integer numbers: the firmware's real-time arithmetic.

A number is a coefficient ``C`` with ``X`` significant digits and a decimal exponent ``E``;
its value is ``C * 10**E``. It is always normalised: ``10**(X-1) <= |C| < 10**X``, or
``C == 0`` with ``E == 0``. ``X`` defaults to 4, so the product of two coefficients fits a
signed 32-bit integer; ``X`` may be 1..9, which keeps everything within signed 64 bits.

The module has two layers:

* a functional core, ``sci_mul``, ``sci_div``, ``sci_add``, ``sci_sub``, ``sci_normalize``,
  ``sci_compare``, ``sci_from_int`` and ``sci_to_int``, on plain ints and tuples of ints, with
  the integer semantics of the C firmware (division truncates toward zero). The core expects
  normalised operands of one digit count and does no validation; it is written so that numba
  compiles it unchanged in meaning: register every function of ``NUMBA_CORE`` with
  ``numba.extending.register_jitable`` and call them from ``@njit`` code on int64.
* ``SciNumber``, an immutable value type over the core that validates its inputs.

Algorithms (seed 000, with the errata of DESIGN.md section 10)
-----------------------------------------------------------------
multiply
    ``A = C1*C2``; if ``|A| >= 10**(2X-1)`` then ``C3 = A / 10**X`` and ``B = X``, else
    ``C3 = A / 10**(X-1)`` and ``B = X-1``; ``E3 = B + E1 + E2``.
divide
    ``D = C1*10**X / C2``; if ``|D| >= 10**X`` then ``C3 = D / 10`` and
    ``E3 = E1 - X - E2 + 1``, else ``C3 = D`` and ``E3 = E1 - X - E2``.
add, subtract
    ``A = E1 - E2``; if ``A >= X`` the result is the first operand, if ``A <= -X`` the second
    (negated for subtraction): the smaller one is below the larger one's last digit
    ("dropped significance"). Otherwise the coefficient with the larger exponent is
    levelled (multiplied by ``10**|A|``), the sum is formed exactly at the smaller exponent,
    and renormalised (a carry gains a digit, a cancellation loses several).

Every ``/`` above truncates toward zero, as C's integer division does.

Intermediate ranges
-------------------
With normalised operands ``|C| <= 10**X - 1``:

* multiply: ``|A| <= (10**X - 1)**2 < 10**(2X)``;
* divide: ``|C1 * 10**X| <= (10**X - 1) * 10**X < 10**(2X)``;
* add/subtract: ``|C * 10**A| + |C'| <= (10**X - 1) * 10**(X-1) + 10**X - 1 < 10**(2X-1) + 10**X``.

For ``X = 4`` the largest is 99,990,000 < 2**31 - 1 = 2,147,483,647; for ``X = 9`` it is
below 10**18 < 2**63 - 1. The tests check every intermediate of every operation against these
limits by running the core on instrumented integers.

Error bound
-----------
Let ``r = C3 * 10**E3`` be a result, ``x`` the exact value of the operation on the operands'
represented values, and ``ulp(r) = 10**E3`` the weight of ``r``'s last digit. Then for every
operation::

    |x - r| < ulp(r) <= 10**(1-X) * |r|

* multiply, divide, and add/subtract with ``|E1 - E2| < X``: ``r`` is ``x`` truncated toward
  zero to ``X`` significant digits. So ``|r| <= |x|`` with the same sign, and also
  ``|x - r| < 10**(1-X) * |x|``. One truncation happens per operation (the division's two
  truncations compose into one, since ``trunc(trunc(q) / 10) == trunc(q / 10)``). A sum or
  difference whose exact value has at most ``X`` significant digits is exact; in particular a
  cancellation is exact on the levelled coefficients and an exact zero gives ``0e0``.
* add/subtract with ``|E1 - E2| >= X`` (dropped significance): ``r`` is the operand with the
  larger exponent (sign compensated for subtraction) and the error is the dropped operand
  ``s``, with ``|s| < 10**(X + E_small) <= 10**E_large = ulp(r)``. So the bound above holds
  relative to ``r``; relative to ``x`` it is ``10**(1-X) / (1 - 10**(1-X))`` for ``X >= 2``.
  Here ``|r|`` may exceed ``|x|``: subtracting a negligible number does not "roll down" the
  last digit, as the seed requires.

For ``X = 4`` each operation therefore loses less than 0.1 % of its result. Errors
compound across operations and with the truncation of the inputs: the seed's example
``892837 * 0.0928182`` becomes ``8928e2 * 9281e-5 = 8286e1``, 0.014 % below the exact
82871.52 (the seed quotes 0.8 %, which is not what its own figures give).

Comparison is exact. Accumulators that must not lose small increments (encoder counts,
integrator sums) are plain integers, not scientific numbers: see DESIGN.md section 3.1.
"""

from __future__ import annotations

import math
import re
import reprlib
from fractions import Fraction
from typing import Any, Final, final

from usbmotion.errors import SciMathError

__all__ = [
    "DEFAULT_DIGITS",
    "MAX_DIGITS",
    "MIN_DIGITS",
    "NUMBA_CORE",
    "SciNumber",
    "sci_add",
    "sci_compare",
    "sci_div",
    "sci_from_int",
    "sci_mul",
    "sci_normalize",
    "sci_sub",
    "sci_to_int",
]

DEFAULT_DIGITS: Final = 4
"""Significant digits of the firmware's numbers: coefficient products fit signed 32 bits."""
MIN_DIGITS: Final = 1
MAX_DIGITS: Final = 9
"""Most significant digits whose intermediates all fit signed 64 bits."""

_POW10: Final = tuple(10**k for k in range(19))


# --- functional core (plain ints; numba-compilable) ---------------------------------------


def _tdiv(a: int, b: int) -> int:
    """Integer quotient ``a / b`` truncated toward zero, as C's ``/`` (``b != 0``)."""
    magnitude = (-a if a < 0 else a) // (-b if b < 0 else b)
    if (a < 0) != (b < 0):
        return -magnitude
    return magnitude


def sci_normalize(c: int, e: int, digits: int) -> tuple[int, int]:
    """Normalise ``c * 10**e`` to ``digits`` significant digits, truncating toward zero.

    Returns ``(C, E)`` with ``10**(digits-1) <= |C| < 10**digits``, or ``(0, 0)``.
    """
    if c == 0:
        return 0, 0
    magnitude = -c if c < 0 else c
    upper = _POW10[digits]
    lower = _POW10[digits - 1]
    while magnitude >= upper:
        magnitude //= 10
        e += 1
    while magnitude < lower:
        magnitude *= 10
        e -= 1
    if c < 0:
        return -magnitude, e
    return magnitude, e


def sci_from_int(value: int, digits: int) -> tuple[int, int]:
    """The integer ``value`` truncated toward zero to ``digits`` significant digits."""
    return sci_normalize(value, 0, digits)


def sci_to_int(c: int, e: int) -> int:
    """The value ``c * 10**e`` as an integer, truncated toward zero."""
    if e >= 0:
        scale: int = 10**e
        return c * scale
    magnitude = -c if c < 0 else c
    while e < 0 and magnitude != 0:
        magnitude //= 10
        e += 1
    if c < 0:
        return -magnitude
    return magnitude


def sci_mul(c1: int, e1: int, c2: int, e2: int, digits: int) -> tuple[int, int]:
    """Product of two normalised numbers, truncated toward zero to ``digits`` digits."""
    a = c1 * c2
    if a == 0:
        return 0, 0
    threshold = _POW10[2 * digits - 1]
    if a >= threshold or a <= -threshold:
        return _tdiv(a, _POW10[digits]), e1 + e2 + digits
    return _tdiv(a, _POW10[digits - 1]), e1 + e2 + digits - 1


def sci_div(c1: int, e1: int, c2: int, e2: int, digits: int) -> tuple[int, int]:
    """Quotient of two normalised numbers, truncated toward zero to ``digits`` digits.

    Raises ZeroDivisionError when ``c2 == 0``.
    """
    if c2 == 0:
        raise ZeroDivisionError("scientific-notation division by zero")
    if c1 == 0:
        return 0, 0
    upper = _POW10[digits]
    d = _tdiv(c1 * upper, c2)
    if d >= upper or d <= -upper:
        return _tdiv(d, 10), e1 - e2 - digits + 1
    return d, e1 - e2 - digits


def sci_add(c1: int, e1: int, c2: int, e2: int, digits: int) -> tuple[int, int]:
    """Sum of two normalised numbers, truncated toward zero to ``digits`` digits.

    An operand whose exponent is ``digits`` or more below the other's is dropped.
    """
    if c1 == 0:
        return c2, e2
    if c2 == 0:
        return c1, e1
    shift = e1 - e2
    if shift >= digits:
        return c1, e1
    if shift <= -digits:
        return c2, e2
    if shift >= 0:
        return sci_normalize(c1 * _POW10[shift] + c2, e2, digits)
    return sci_normalize(c1 + c2 * _POW10[-shift], e1, digits)


def sci_sub(c1: int, e1: int, c2: int, e2: int, digits: int) -> tuple[int, int]:
    """Difference of two normalised numbers, truncated toward zero to ``digits`` digits.

    An operand whose exponent is ``digits`` or more below the other's is dropped.
    """
    return sci_add(c1, e1, -c2, e2, digits)


def _sign(c: int) -> int:
    if c > 0:
        return 1
    if c < 0:
        return -1
    return 0


def sci_compare(c1: int, e1: int, c2: int, e2: int) -> int:
    """-1, 0 or 1 as ``c1e1`` is below, equal to or above ``c2e2`` (exact).

    Both operands must be normalised to the same number of digits.
    """
    s1 = _sign(c1)
    s2 = _sign(c2)
    if s1 != s2:
        if s1 > s2:
            return 1
        return -1
    if s1 == 0:
        return 0
    if e1 != e2:
        if e1 > e2:
            return s1
        return -s1
    if c1 == c2:
        return 0
    if c1 > c2:
        return 1
    return -1


NUMBA_CORE: Final = (
    _tdiv,
    _sign,
    sci_normalize,
    sci_from_int,
    sci_to_int,
    sci_mul,
    sci_div,
    sci_add,
    sci_sub,
    sci_compare,
)
"""The core functions, callees first: register each with ``register_jitable`` to use in numba."""


# --- the value type -----------------------------------------------------------------------


_DECIMAL = re.compile(r"([+-]?)(?:([0-9]+)(?:\.([0-9]*))?|\.([0-9]+))(?:[eE]([+-]?[0-9]+))?")
_FLOAT_EDGE_EXPONENT: Final = 400


def _check_digits(digits: object) -> int:
    if isinstance(digits, bool) or not isinstance(digits, int):
        raise SciMathError(f"digits {digits!r} is not an int; allowed {MIN_DIGITS}..{MAX_DIGITS}")
    if not MIN_DIGITS <= digits <= MAX_DIGITS:
        raise SciMathError(
            f"digits {digits!r} is out of range; allowed {MIN_DIGITS}..{MAX_DIGITS} "
            f"(more than {MAX_DIGITS} overflows signed 64-bit intermediates)"
        )
    return digits


def _check_int(name: str, value: object) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise SciMathError(f"{name} {value!r} is a {type(value).__name__}; expected an int")
    return value


@final
class SciNumber:
    """An immutable scientific-notation integer number ``coefficient * 10**exponent``.

    Always normalised: ``10**(digits-1) <= |coefficient| < 10**digits``, or zero as
    ``SciNumber(0, 0)``. Supports ``* / + -`` between numbers of the same ``digits``, unary
    ``-``, ``abs``, exact comparisons (also across digit counts), ``float``, ``int``
    (truncating toward zero) and hashing consistent with ``==``. See the module docstring
    for the algorithms and their error bound.
    """

    __slots__ = ("coefficient", "digits", "exponent")

    coefficient: int
    exponent: int
    digits: int

    def __init__(self, coefficient: int, exponent: int, *, digits: int = DEFAULT_DIGITS) -> None:
        """Build ``coefficient * 10**exponent`` exactly.

        ``coefficient`` may have fewer than ``digits`` digits (it is normalised without
        loss); ``digits`` is 1..9.

        Raises:
            SciMathError: a non-int or bool coefficient or exponent, a coefficient with more
                than ``digits`` digits (use ``from_int`` to truncate), or ``digits`` outside
                1..9.
        """
        digits = _check_digits(digits)
        coefficient = _check_int("coefficient", coefficient)
        exponent = _check_int("exponent", exponent)
        limit = _POW10[digits]
        if not -limit < coefficient < limit:
            raise SciMathError(
                f"coefficient {coefficient!r} has {len(str(abs(coefficient)))} significant "
                f"digits; at most {digits} (digits={digits}); SciNumber.from_int truncates"
            )
        c, e = sci_normalize(coefficient, exponent, digits)
        _set_coefficient(self, c)
        _set_exponent(self, e)
        _set_digits(self, digits)

    # constructors

    @classmethod
    def from_int(cls, value: int, *, digits: int = DEFAULT_DIGITS) -> SciNumber:
        """The integer ``value`` truncated toward zero to ``digits`` significant digits.

        ``SciNumber.from_int(4921392)`` is ``4921e3``.

        Raises:
            SciMathError: ``value`` is not an int (or is a bool); ``digits`` outside 1..9.
        """
        digits = _check_digits(digits)
        value = _check_int("value", value)
        c, e = sci_from_int(value, digits)
        return _make(c, e, digits)

    @classmethod
    def from_string(cls, text: str, *, digits: int = DEFAULT_DIGITS) -> SciNumber:
        """Parse a decimal (``"-42"``, ``"0.0928182"``) or scientific (``"1.5e-3"``) string.

        The parse is exact; the value is then truncated toward zero to ``digits`` digits.
        Surrounding whitespace is ignored.

        Raises:
            SciMathError: ``text`` is not a string, is not a finite decimal number (NaN,
                infinities, underscores, hexadecimal, garbage), or ``digits`` is outside 1..9.
        """
        digits = _check_digits(digits)
        if not isinstance(text, str):
            raise SciMathError(
                f"text {reprlib.repr(text)} is a {type(text).__name__}; expected a str"
            )
        match = _DECIMAL.fullmatch(text.strip())
        if match is None:
            raise SciMathError(
                f"text {reprlib.repr(text)} is not a finite decimal number; expected forms like "
                "'-42', '0.0928182' or '1.5e-3'"
            )
        sign, whole, fraction, bare_fraction, exponent_text = match.groups()
        if bare_fraction is not None:
            whole, fraction = "", bare_fraction
        fraction = fraction or ""
        try:
            exponent = int(exponent_text) if exponent_text else 0
        except ValueError:
            raise SciMathError(
                f"text {reprlib.repr(text)} has an exponent too long to convert; expected a number "
                "within Python's integer string limit"
            ) from None
        significant = (whole + fraction).lstrip("0")
        if not significant:
            return _make(0, 0, digits)
        exponent -= len(fraction)
        excess = len(significant) - digits
        if excess > 0:
            c, e = int(significant[:digits]), exponent + excess
        else:
            c, e = int(significant) * _POW10[-excess], exponent + excess
        return _make(-c if sign == "-" else c, e, digits)

    @classmethod
    def from_float(cls, value: float, *, digits: int = DEFAULT_DIGITS) -> SciNumber:
        """The float ``value`` via its shortest exact decimal ``repr``, truncated to ``digits``.

        ``from_float(0.3)`` is ``3000e-4`` (the decimal ``0.3``, not the binary expansion
        ``0.29999...``).

        Raises:
            SciMathError: ``value`` is NaN, infinite, a bool or not a number; ``digits``
                outside 1..9.
        """
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise SciMathError(
                f"value {value!r} is a {type(value).__name__}; expected a finite float or an int"
            )
        if isinstance(value, int):
            return cls.from_int(value, digits=digits)
        if not math.isfinite(value):
            raise SciMathError(f"value {value!r} is not finite; expected a finite float")
        return cls.from_string(repr(float(value)), digits=digits)

    def with_digits(self, digits: int) -> SciNumber:
        """This number with ``digits`` significant digits (truncated toward zero if fewer).

        Raises:
            SciMathError: ``digits`` outside 1..9.
        """
        digits = _check_digits(digits)
        c, e = sci_normalize(self.coefficient, self.exponent, digits)
        return _make(c, e, digits)

    # conversions

    def to_fraction(self) -> Fraction:
        """The exact value as a ``fractions.Fraction``."""
        if self.exponent >= 0:
            return Fraction(self.coefficient * 10**self.exponent)
        return Fraction(self.coefficient, 10**-self.exponent)

    def __float__(self) -> float:
        """The nearest float (correctly rounded); OverflowError when beyond float's range."""
        c, e = self.coefficient, self.exponent
        if e >= 0:
            if e > _FLOAT_EDGE_EXPONENT:
                raise OverflowError(f"{self} is too large to convert to float")
            return float(c * 10**e)
        if e < -_FLOAT_EDGE_EXPONENT:
            return math.copysign(0.0, c)
        scale: int = 10**-e
        return c / scale

    def __int__(self) -> int:
        """The value truncated toward zero."""
        return sci_to_int(self.coefficient, self.exponent)

    def __trunc__(self) -> int:
        return sci_to_int(self.coefficient, self.exponent)

    def __bool__(self) -> bool:
        return self.coefficient != 0

    def __repr__(self) -> str:
        if self.digits == DEFAULT_DIGITS:
            return f"SciNumber({self.coefficient}, {self.exponent})"
        return f"SciNumber({self.coefficient}, {self.exponent}, digits={self.digits})"

    def __str__(self) -> str:
        return f"{self.coefficient}e{self.exponent}"

    # arithmetic

    def __mul__(self, other: SciNumber) -> SciNumber:
        if not isinstance(other, SciNumber):
            return NotImplemented
        digits = self.digits
        if other.digits != digits:
            raise _mixed_digits(self, "*", other)
        c, e = sci_mul(self.coefficient, self.exponent, other.coefficient, other.exponent, digits)
        return _make(c, e, digits)

    def __truediv__(self, other: SciNumber) -> SciNumber:
        if not isinstance(other, SciNumber):
            return NotImplemented
        digits = self.digits
        if other.digits != digits:
            raise _mixed_digits(self, "/", other)
        if other.coefficient == 0:
            raise ZeroDivisionError(f"SciNumber division by zero: {self} / {other}")
        c, e = sci_div(self.coefficient, self.exponent, other.coefficient, other.exponent, digits)
        return _make(c, e, digits)

    def __add__(self, other: SciNumber) -> SciNumber:
        if not isinstance(other, SciNumber):
            return NotImplemented
        digits = self.digits
        if other.digits != digits:
            raise _mixed_digits(self, "+", other)
        c, e = sci_add(self.coefficient, self.exponent, other.coefficient, other.exponent, digits)
        return _make(c, e, digits)

    def __sub__(self, other: SciNumber) -> SciNumber:
        if not isinstance(other, SciNumber):
            return NotImplemented
        digits = self.digits
        if other.digits != digits:
            raise _mixed_digits(self, "-", other)
        c, e = sci_sub(self.coefficient, self.exponent, other.coefficient, other.exponent, digits)
        return _make(c, e, digits)

    def __neg__(self) -> SciNumber:
        return _make(-self.coefficient, self.exponent, self.digits)

    def __pos__(self) -> SciNumber:
        return self

    def __abs__(self) -> SciNumber:
        if self.coefficient >= 0:
            return self
        return _make(-self.coefficient, self.exponent, self.digits)

    # comparison

    def _compare(self, other: SciNumber) -> int:
        if other.digits == self.digits:
            return sci_compare(self.coefficient, self.exponent, other.coefficient, other.exponent)
        wide = max(self.digits, other.digits)
        c1, e1 = sci_normalize(self.coefficient, self.exponent, wide)
        c2, e2 = sci_normalize(other.coefficient, other.exponent, wide)
        return sci_compare(c1, e1, c2, e2)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, SciNumber):
            return NotImplemented
        if other.digits == self.digits:
            return self.coefficient == other.coefficient and self.exponent == other.exponent
        return self._compare(other) == 0

    def __lt__(self, other: SciNumber) -> bool:
        if not isinstance(other, SciNumber):
            return NotImplemented
        return self._compare(other) < 0

    def __le__(self, other: SciNumber) -> bool:
        if not isinstance(other, SciNumber):
            return NotImplemented
        return self._compare(other) <= 0

    def __gt__(self, other: SciNumber) -> bool:
        if not isinstance(other, SciNumber):
            return NotImplemented
        return self._compare(other) > 0

    def __ge__(self, other: SciNumber) -> bool:
        if not isinstance(other, SciNumber):
            return NotImplemented
        return self._compare(other) >= 0

    def __hash__(self) -> int:
        c, e = self.coefficient, self.exponent
        if c == 0:
            return hash((0, 0))
        while c % 10 == 0:
            c //= 10
            e += 1
        return hash((c, e))

    # immutability

    def __setattr__(self, name: str, value: object) -> None:
        raise AttributeError(f"SciNumber is immutable; cannot set {name!r}")

    def __delattr__(self, name: str) -> None:
        raise AttributeError(f"SciNumber is immutable; cannot delete {name!r}")

    def __reduce__(self) -> tuple[Any, tuple[int, int, int]]:
        return _make, (self.coefficient, self.exponent, self.digits)


_set_coefficient = SciNumber.__dict__["coefficient"].__set__
_set_exponent = SciNumber.__dict__["exponent"].__set__
_set_digits = SciNumber.__dict__["digits"].__set__


def _make(c: int, e: int, digits: int) -> SciNumber:
    """A SciNumber from an already normalised ``(c, e)``, without validation."""
    number = object.__new__(SciNumber)
    _set_coefficient(number, c)
    _set_exponent(number, e)
    _set_digits(number, digits)
    return number


def _mixed_digits(left: SciNumber, operator: str, right: SciNumber) -> SciMathError:
    return SciMathError(
        f"cannot compute {left!r} {operator} {right!r}: digits={left.digits} and "
        f"digits={right.digits} differ; convert one with with_digits()"
    )
