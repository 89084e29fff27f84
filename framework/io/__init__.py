"""File formats: readers and writers used by the io plugins.

Each function raises :class:`rigslim.errors.InputError` naming the file and
the field for anything malformed, and writers go through
:func:`rigslim.io.atomic.atomic_path` so a failure leaves no partial file.
"""

from rigslim.io.animation import read_stacked_animation
from rigslim.io.atomic import atomic_path
from rigslim.io.dmat import read_dmat, write_dmat
from rigslim.io.meshfile import read_medit_surface, read_mesh
from rigslim.io.reduced import read_reduced_npz, write_reduced_npz
from rigslim.io.tgf import read_tgf

__all__ = ["atomic_path", "read_dmat", "write_dmat", "read_mesh", "read_medit_surface", "read_tgf",
           "read_stacked_animation", "read_reduced_npz", "write_reduced_npz"]
