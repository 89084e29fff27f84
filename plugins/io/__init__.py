"""Readers and writers of the file formats rigslim ships with.

Readers: OBJ/OFF/PLY/STL and MEDIT ``.mesh`` (libigl), DMAT weights, TGF
skeletons, libigl's stacked-transform DMAT animation, a closed cage mesh.
Writers: DMAT (dense reduced weights) and ``.npz`` (fixed-k reduced weights).
glTF 2.0 reader and writer: :mod:`rigslim.plugins.io.gltf`; USD / UsdSkel: :mod:`rigslim.plugins.io.usd`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from rigslim import hookimpl
from rigslim.plugins.io.gltf import READERS as GLTF_READERS
from rigslim.plugins.io.gltf import WRITERS as GLTF_WRITERS
from rigslim.plugins.io.readers import READERS
from rigslim.plugins.io.usd import READERS as USD_READERS
from rigslim.plugins.io.usd import WRITERS as USD_WRITERS
from rigslim.plugins.io.writers import WRITERS

if TYPE_CHECKING:
    from rigslim.plugin import Reader, Writer


@hookimpl
def rigslim_readers() -> list[Reader]:
    return [cls() for cls in READERS + GLTF_READERS + USD_READERS]


@hookimpl
def rigslim_writers() -> list[Writer]:
    return [cls() for cls in WRITERS + GLTF_WRITERS + USD_WRITERS]
