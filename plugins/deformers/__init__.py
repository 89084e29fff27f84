"""Deformer plugins: linear blending of handle transforms on a back end."""

from __future__ import annotations

from typing import TYPE_CHECKING

from rigslim import hookimpl
from rigslim.plugins.deformers.cpu_deformer import CPUDeformer
from rigslim.plugins.deformers.numpy_deformer import NumpyDeformer
from rigslim.plugins.deformers.opencl_deformer import OpenCLDeformer
from rigslim.plugins.deformers.opengl_deformer import OpenGLDeformer

if TYPE_CHECKING:
    from rigslim.plugin import Deformer


@hookimpl
def rigslim_deformers() -> list[Deformer]:
    return [NumpyDeformer(), CPUDeformer(), OpenCLDeformer(), OpenGLDeformer()]
