"""daemon/storage/float_text.py: msgspec's float text rewritten into Python's repr, checked
against repr itself on doubles of every kind (the exports' byte-for-byte contract)."""

from __future__ import annotations

import math

import numpy as np

from daemon.storage.float_text import float_text


def _reprs(values: list[float]) -> list[bytes]:
    return [b"null" if not math.isfinite(v) else repr(v).encode() for v in values]


def _check(values: list[float]) -> None:
    got = float_text(values).split(b",")
    expected = _reprs(values)
    wrong = [(v, g, e) for v, g, e in zip(values, got, expected, strict=True) if g != e]
    assert not wrong, wrong[:5]


def test_layouts_that_differ_from_msgspecs() -> None:
    values = [1e16, 1e-05, 1.5e-05, 9.999e-05, 0.0001, 1e-07, 1.2345678901234568e17, 3.0]
    values += [-0.0, 5e-324, 1.7976931348623157e308, 1e22, 0.1, 9999999999999998.0, 1e15]
    values += [10.00001, -1.5e-05, -0.00001, 1e100, 1e-100, 2.5e-10]
    _check(values)
    assert float_text([1e-05, -1.5e-05, 10.00001, 1e16]) == b"1e-05,-1.5e-05,10.00001,1e+16"


def test_none_and_non_finite_are_null() -> None:
    assert float_text([None, math.inf, -math.inf, math.nan, 2.0]) == b"null,null,null,null,2.0"
    assert float_text([]) == b""


def test_random_doubles_every_decade_and_powers_of_two() -> None:
    rng = np.random.default_rng(30)
    _check(rng.integers(0, 2**64, size=200_000, dtype=np.uint64).view(np.float64).tolist())
    for exponent in range(-323, 308):
        scale = 10.0**exponent
        decade = [*(rng.random(50) * scale).tolist(), scale, -scale]
        decade += [float(np.nextafter(scale, 0.0)), float(np.nextafter(scale, math.inf))]
        _check(decade)
    powers = [2.0**k for k in range(-1074, 1024)]
    powers += [float(np.nextafter(p, 0.0)) for p in powers] + [
        float(np.nextafter(p, math.inf)) for p in powers[:-1]
    ]
    _check(powers)
    _check([i / 1000 for i in range(-20_000, 20_000)] + [i * 1e-5 for i in range(20_000)])
