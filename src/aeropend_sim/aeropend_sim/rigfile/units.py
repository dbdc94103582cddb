"""Quantities typed by a person (``0.12kg``, ``80ms``, ``1100us``) converted to a parameter's SI unit.

A unit is a product of powers of named units, each with an optional SI prefix: ``kg``, ``g``,
``ms``, ``mm``, ``N*m/A``, ``1/(kg*m)``, ``rad/s``, ``rpm``, ``deg``, ``%``. Each is reduced to a
factor and the exponents of the base quantities (kg, m, s, A, rad); a value is converted when its
unit has the same exponents as the parameter's unit (the one in the registry, which the rig format
checks), and refused otherwise, naming both. Angles are kept as their own base (``rad``) so that
``deg`` and ``rpm`` convert; a unit without an angle matches one with ``rad`` only where the
parameter's unit has none either.

No dependency: the handful of units a lab types for an aeropendulum (SciPy's ``constants`` holds
factors, not a unit algebra).
"""

from __future__ import annotations

import math
import re

#: Base quantities of a dimension vector.
BASES = ("kg", "m", "s", "A", "rad")

_KG, _M, _S, _A, _RAD = (tuple(int(i == k) for i in range(5)) for k in range(5))


def _dim(**e: int) -> tuple[int, ...]:
    return tuple(e.get(b, 0) for b in BASES)


#: Named units: factor to SI and dimension exponents over :data:`BASES`.
UNITS: dict[str, tuple[float, tuple[int, ...]]] = {
    "1": (1.0, _dim()), "%": (0.01, _dim()),
    "kg": (1.0, _dim(kg=1)), "g": (1e-3, _dim(kg=1)),
    "m": (1.0, _dim(m=1)), "s": (1.0, _dim(s=1)), "min": (60.0, _dim(s=1)),
    "A": (1.0, _dim(A=1)), "rad": (1.0, _dim(rad=1)), "deg": (math.pi / 180.0, _dim(rad=1)),
    "rev": (2.0 * math.pi, _dim(rad=1)), "rpm": (2.0 * math.pi / 60.0, _dim(rad=1, s=-1)),
    "Hz": (1.0, _dim(s=-1)),
    "N": (1.0, _dim(kg=1, m=1, s=-2)),
    "V": (1.0, _dim(kg=1, m=2, s=-3, A=-1)),
    "ohm": (1.0, _dim(kg=1, m=2, s=-3, A=-2)), "Ω": (1.0, _dim(kg=1, m=2, s=-3, A=-2)),
    "H": (1.0, _dim(kg=1, m=2, s=-2, A=-2)),
}
#: SI prefixes accepted before a named unit (not before ``1``, ``%``, ``kg``, ``min``, ``rpm``).
PREFIXES = {"n": 1e-9, "u": 1e-6, "µ": 1e-6, "μ": 1e-6, "m": 1e-3, "c": 1e-2, "k": 1e3, "M": 1e6}
_NO_PREFIX = {"1", "%", "kg", "min", "rpm", "rev", "deg"}


class UnitError(ValueError):
    """A unit that cannot be read, or that does not convert to the expected one."""


def _name(token: str) -> tuple[float, tuple[int, ...]]:
    if token in UNITS:
        return UNITS[token]
    if len(token) > 1 and token[0] in PREFIXES and token[1:] in UNITS and token[1:] not in _NO_PREFIX:
        factor, dim = UNITS[token[1:]]
        return PREFIXES[token[0]] * factor, dim
    raise UnitError(f"unknown unit {token!r}; expected one of {sorted(UNITS)} with an optional SI prefix "
                    f"({''.join(sorted(set(PREFIXES) - {'μ'}))})")


_TOKEN = re.compile(r"\s*([A-Za-zµμΩ%]+|\d+|[*/^()·-])")


def parse_unit(text: str) -> tuple[float, tuple[int, ...]]:
    """(factor to SI, dimension exponents over :data:`BASES`) of a unit string.

    Raises
    ------
    UnitError
        On an unknown name or a malformed expression.
    """
    src = str(text).replace("·", "*").replace("²", "^2").replace("³", "^3").strip() or "1"
    tokens, pos = [], 0
    while pos < len(src):
        m = _TOKEN.match(src, pos)
        if m is None:
            raise UnitError(f"cannot read unit {text!r} at {src[pos:]!r}")
        tokens.append(m.group(1))
        pos = m.end()
    out, rest = _product(tokens, text)
    if rest:
        raise UnitError(f"cannot read unit {text!r}: unexpected {''.join(rest)!r}")
    return out


def _product(tokens: list[str], text: str) -> tuple[tuple[float, tuple[int, ...]], list[str]]:
    (factor, dim), tokens = _power(tokens, text)
    while tokens and tokens[0] in "*/":
        op, tokens = tokens[0], tokens[1:]
        (f, d), tokens = _power(tokens, text)
        sign = 1 if op == "*" else -1
        factor *= f**sign
        dim = tuple(a + sign * b for a, b in zip(dim, d, strict=True))
    return (factor, dim), tokens


def _power(tokens: list[str], text: str) -> tuple[tuple[float, tuple[int, ...]], list[str]]:
    if not tokens:
        raise UnitError(f"cannot read unit {text!r}: it ends early")
    head, tokens = tokens[0], tokens[1:]
    if head == "(":
        inner, tokens = _product(tokens, text)
        if not tokens or tokens[0] != ")":
            raise UnitError(f"cannot read unit {text!r}: unbalanced parentheses")
        (factor, dim), tokens = inner, tokens[1:]
    elif head.isdigit():
        if head != "1":
            raise UnitError(f"cannot read unit {text!r}: a number {head!r} where a unit was expected")
        factor, dim = 1.0, _dim()
    else:
        factor, dim = _name(head)
    if tokens and tokens[0] == "^":
        neg = len(tokens) > 1 and tokens[1] == "-"
        k = 2 + int(neg)
        if len(tokens) < k or not tokens[k - 1].isdigit():
            raise UnitError(f"cannot read unit {text!r}: '^' needs a whole exponent")
        e = int(tokens[k - 1]) * (-1 if neg else 1)
        factor, dim, tokens = factor**e, tuple(x * e for x in dim), tokens[k:]
    return (factor, dim), tokens


_QUANTITY = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*(.*?)\s*$")


def convert(text: str, unit: str, what: str = "value") -> float:
    """The number of a quantity ``"0.12kg"`` / ``"80 ms"`` / ``"3"`` in ``unit`` (a registry unit).

    A bare number is taken in ``unit`` itself.

    Raises
    ------
    UnitError
        If ``text`` is not a number with an optional unit, or its unit does not convert to ``unit``
        (the message names ``what``, both units and their dimensions).
    """
    m = _QUANTITY.match(str(text))
    if m is None:
        raise UnitError(f"{what} = {text!r}: expected a number with an optional unit, e.g. 0.12kg or 80ms")
    value = float(m.group(1))
    if not math.isfinite(value):
        raise UnitError(f"{what} = {text!r} is not finite")
    given = m.group(2)
    if not given:
        return value
    f_in, d_in = parse_unit(given)
    f_out, d_out = parse_unit(unit)
    if d_in != d_out:
        raise UnitError(f"{what} = {text!r}: unit {given!r} does not convert to {unit!r} "
                        f"({_dims(d_in)} vs {_dims(d_out)})")
    return value * f_in / f_out


def _dims(d: tuple[int, ...]) -> str:
    parts = [b if e == 1 else f"{b}^{e}" for b, e in zip(BASES, d, strict=True) if e]
    return "·".join(parts) or "dimensionless"
