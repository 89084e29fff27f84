"""File formats: readers and writers used by the io plugins.

Meshes (:mod:`~rigslim.io.meshfile`), skeletons (:mod:`~rigslim.io.tgf`), matrices (:mod:`~rigslim.io.dmat`),
animations (:mod:`~rigslim.io.animation`), reduced weights (:mod:`~rigslim.io.reduced`), progressive
hierarchies (:mod:`~rigslim.io.hierarchy`), glTF (:mod:`rigslim.io.gltf`, a package), quaternions and TRS
(:mod:`~rigslim.io.transforms`), YAML documents (:mod:`~rigslim.io.yamlio`), strict JSON
(:mod:`~rigslim.io.jsonsafe`) and atomic outputs (:mod:`~rigslim.io.atomic`).

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
