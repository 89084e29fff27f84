"""rigslim.model.units: error bounds in % of the diagonal or in metres."""

from __future__ import annotations

import pytest

from rigslim.errors import StepError
from rigslim.model.units import parse_length_bound


def test_percent_metres_and_none():
    assert parse_length_bound(1) == (1.0, "%") and parse_length_bound(0.25) == (0.25, "%")
    assert parse_length_bound("1%") == (1.0, "%") and parse_length_bound("1.5e-1 %") == (0.15, "%")
    assert parse_length_bound("0.02m") == (0.02, "m")
    for off in (None, "none", "OFF", " none "):
        assert parse_length_bound(off) is None


@pytest.mark.parametrize("bad", ["2cm", "-1", "0", "0m", "one", "1%%", True])
def test_bad_bounds_name_the_field(bad):
    with pytest.raises(StepError, match="--max-error"):
        parse_length_bound(bad, "--max-error")
