import numpy as np
import pytest

from rigslim.errors import InputError
from rigslim.io import read_tgf


def test_elephant_skeleton(data_dir):
    h = read_tgf(data_dir / "elephant.tgf")
    assert h.kind == "skeleton" and h.n == 24
    assert h.joints.shape == (25, 3)
    # bones 0-5 are a chain from the root joint; bone 6 starts at the end of bone 2.
    assert list(h.parents[:7]) == [-1, 0, 1, 2, 3, 4, 2]
    np.testing.assert_array_equal(h.rest_transforms()[:, :, :3], np.broadcast_to(np.eye(3), (24, 3, 3)))


def test_extra_columns_are_ignored(tmp_path):
    (tmp_path / "s.tgf").write_text("1 0 0 0 9 9 9\n2 0 1 0 8 8\n#\n1 2 1 0\n#\n")
    h = read_tgf(tmp_path / "s.tgf")
    assert h.n == 1 and h.joints[1, 1] == 1.0


@pytest.mark.parametrize("text", ["1 0 0\n#\n1 2\n#\n", "1 0 0 0\n#\n1 5\n#\n", "1 0 0 0\n#\n#\n"])
def test_malformed(tmp_path, text):
    (tmp_path / "s.tgf").write_text(text)
    with pytest.raises(InputError):
        read_tgf(tmp_path / "s.tgf")
