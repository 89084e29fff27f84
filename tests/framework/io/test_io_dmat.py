import numpy as np
import pytest

from rigslim.errors import InputError
from rigslim.io import read_dmat, write_dmat


@pytest.mark.parametrize("binary", [True, False])
def test_round_trip(tmp_path, rng, binary):
    M = rng.standard_normal((7, 3))
    write_dmat(tmp_path / "m.dmat", M, binary=binary)
    np.testing.assert_array_equal(read_dmat(tmp_path / "m.dmat"), M)


def test_reads_libigl_ascii_column_major(tmp_path):
    (tmp_path / "a.dmat").write_text("2 3\n1\n2\n3\n4\n5\n6\n")  # cols rows, then column-major
    np.testing.assert_array_equal(read_dmat(tmp_path / "a.dmat"), [[1, 4], [2, 5], [3, 6]])


def test_reads_real_binary_file(data_dir):
    W = read_dmat(data_dir / "elephant-weights.dmat")
    assert W.shape == (6034, 24)
    np.testing.assert_allclose(W.sum(axis=1), 1.0, atol=1e-12)


@pytest.mark.parametrize("text,field", [("2 3\n1\n2\n", "values"), ("x y\n", "header"), ("1 2\n1\nfoo\n", "values")])
def test_malformed_files_name_file_and_field(tmp_path, text, field):
    p = tmp_path / "bad.dmat"
    p.write_text(text)
    with pytest.raises(InputError) as e:
        read_dmat(p)
    assert e.value.field == field and "bad.dmat" in str(e.value)


def test_truncated_binary(tmp_path):
    p = tmp_path / "t.dmat"
    p.write_bytes(b"0 0\n2 2\n" + np.zeros(3).tobytes())
    with pytest.raises(InputError, match="truncated"):
        read_dmat(p)


def test_missing_file(tmp_path):
    with pytest.raises(InputError, match="cannot read"):
        read_dmat(tmp_path / "nope.dmat")


def test_failed_write_leaves_no_file(tmp_path):
    class Boom:
        def __array__(self, *a, **k):
            raise RuntimeError("boom")

    with pytest.raises(RuntimeError, match="boom"):
        write_dmat(tmp_path / "x.dmat", Boom())
    assert list(tmp_path.iterdir()) == []


def test_outputs_get_umask_permissions(tmp_path):
    import os

    write_dmat(tmp_path / "p.dmat", np.eye(2))
    mask = os.umask(0)
    os.umask(mask)
    assert (tmp_path / "p.dmat").stat().st_mode & 0o777 == 0o666 & ~mask
