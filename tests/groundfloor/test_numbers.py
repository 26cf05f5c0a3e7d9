"""Numbers rounded to their precision (two significant digits of the standard deviation, GUM 7.2.6)."""

from __future__ import annotations

import numpy as np

from groundfloor.numbers import decimals_for, format_sig, format_with_std


def test_estimate_with_std_keeps_two_digits_of_the_std():
    assert format_with_std(6.932989123, 1.74e-5, unit="m") == "6.932989 +- 0.000017 m"
    assert format_with_std(-0.0123456, 0.00052) == "-0.01235 +- 0.00052"
    assert format_with_std(0.5, 0.25, sign=True) == "+0.50 +- 0.25"
    assert format_with_std(1234.7, 23.0) == "1235 +- 23"
    assert format_with_std(1234.7, 230.0) == "1230 +- 230"  # std of hundreds: rounded to tens
    assert decimals_for(0.0) == 6 and decimals_for(float("nan")) == 6


def test_sig_digits_and_other_values():
    assert format_sig(0.000123456) == "0.000123"
    assert format_sig(123456.0) == "1.23e+05"
    assert format_sig({"u1": 0.1367203, "u2": True}) == "{u1: 0.137, u2: True}"
    assert format_sig(float("inf")) == "inf" and format_sig(np.float64("nan")) == "nan"
    assert format_sig(7) == "7" and format_sig(True) == "True" and format_sig("x") == "x"
    assert format_sig([1.23456, np.array(2.0)]) == "[1.23, 2]"
