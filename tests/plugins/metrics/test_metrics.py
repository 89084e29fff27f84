import numpy as np
import pytest

from rigslim.numerics.normal_error import normal_rms_angle
from rigslim.plugins.metrics.position_rms import position_rms


def test_position_rms():
    X = np.zeros((4, 3))
    Y = np.zeros((4, 3))
    Y[0] = [2, 0, 0]
    assert position_rms(X, Y) == pytest.approx(1.0)


def test_normal_angle_small_and_right_angles():
    N = np.tile([0.0, 0.0, 1.0], (2, 1))
    eps = 1e-9
    M = np.array([[np.sin(eps), 0, np.cos(eps)], [1.0, 0.0, 0.0]])
    assert normal_rms_angle(N, M) == pytest.approx(np.sqrt((eps ** 2 + (np.pi / 2) ** 2) / 2))
    assert normal_rms_angle(N[:1], M[:1]) == pytest.approx(eps, rel=1e-6)
