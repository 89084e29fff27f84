import numpy as np
import pytest

from rigslim.errors import InputError
from rigslim.model.poses import FrameSplit, Poses, parse_frames


def test_slice_spec_matches_python():
    assert parse_frames("0:457:45", 457) == list(range(0, 457, 45))
    assert parse_frames("5:457:7", 457) == list(range(5, 457, 7))
    assert parse_frames("1,3,2", 10) == [1, 2, 3]
    assert parse_frames([0, "4:6"], 10) == [0, 4, 5]
    assert parse_frames(":3", 10) == [0, 1, 2]


@pytest.mark.parametrize("spec", ["0:500:5", "12", "a:b", "0:10:0", "", [], "1:2:3:4"])
def test_bad_specs(spec):
    with pytest.raises(InputError):
        parse_frames(spec, 10)


def test_split_drops_overlap():
    s = FrameSplit.from_specs("0:457:45", "5:457:7", 457)
    assert s.dropped == [180]
    assert 180 not in s.test and len(s.test) == 64 and len(s.examples) == 11
    with pytest.raises(InputError, match="every test frame"):
        FrameSplit.from_specs("0:10", "2,3", 10)


def test_poses_select_and_validate():
    T = np.zeros((4, 2, 3, 4))
    p = Poses(T, frames=[10, 11, 12, 13])
    assert list(p.select([12, 10]).frames) == [12, 10]
    with pytest.raises(InputError):
        Poses(np.zeros((4, 2, 3, 3)))
    T[0, 0, 0, 0] = np.inf
    with pytest.raises(InputError):
        Poses(T)
