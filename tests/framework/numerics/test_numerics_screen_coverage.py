"""Switch distances and screen coverage (framework/numerics/screen_coverage.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rigslim.numerics.screen_coverage import coverage_distance, coverage_series, screen_coverage, switch_distance


def test_at_the_switch_distance_the_error_projects_to_p_pixels_at_the_nearest_point():
    r, e, P, fov, H = 0.9, 0.004, 1.5, 60.0, 1080
    d = switch_distance(e, r, pixel_error=P, fov=fov, resolution=H)
    z = d - r                                              # the bounding sphere's nearest point
    pixels = e * H / (2 * z * math.tan(math.radians(fov) / 2))
    assert pixels == pytest.approx(P, rel=1e-12)


def test_coverage_is_the_sphere_disc_over_the_screen_and_inverts():
    r, fov, aspect = 1.2, 45.0, 4 / 3
    for d in (3.0, 10.0, 250.0):
        c = screen_coverage(d, r, fov=fov, aspect=aspect)
        h = 2 * d * math.tan(math.radians(fov) / 2)        # screen height at distance d
        assert c == pytest.approx(math.pi * r * r / (h * h * aspect), rel=1e-12)
        assert coverage_distance(c, r, fov=fov, aspect=aspect) == pytest.approx(d, rel=1e-12)
    assert screen_coverage(1e-3, r) == 1.0                 # clipped


def test_the_series_never_increases_and_ends_at_zero():
    out = coverage_series([0.01, 0.004, 0.03], 1.0)        # a finer level with a larger error than the next
    c = out["coverage"]
    assert len(c) == 4 and c[-1] == 0.0
    assert all(a >= b for a, b in zip(c, c[1:], strict=False))
    assert c[0] == c[1]                                     # the second level waits for the first's distance
    assert out["switch_distance_m"][0] == out["switch_distance_m"][1] < out["switch_distance_m"][2]
    assert np.allclose(out["level_coverage"], c[:3])


def test_fov_cancels_far_away():
    """Far from the object (d >> r) both the error and the object shrink alike: the coverage for a given
    error in pixels hardly depends on the field of view."""
    a = coverage_series([0.1], 1.0, fov=30.0)["coverage"][0]
    b = coverage_series([0.1], 1.0, fov=90.0)["coverage"][0]
    assert a == pytest.approx(b, rel=0.05)
