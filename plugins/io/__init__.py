"""Readers and writers of the file formats rigslim ships with.

Readers: OBJ/OFF/PLY/STL and MEDIT ``.mesh`` (libigl), DMAT weights, TGF
skeletons, libigl's stacked-transform DMAT animation, a closed cage mesh.
Writers: DMAT (dense reduced weights) and ``.npz`` (fixed-k reduced weights).
"""

from rigslim import hookimpl
from rigslim.plugins.io.readers import READERS
from rigslim.plugins.io.writers import WRITERS


@hookimpl
def rigslim_readers():
    return [cls() for cls in READERS]


@hookimpl
def rigslim_writers():
    return [cls() for cls in WRITERS]
