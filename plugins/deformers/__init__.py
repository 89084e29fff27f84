"""Deformer plugins: linear blending of handle transforms on a back end."""

from rigslim import hookimpl
from rigslim.plugins.deformers.cpu_deformer import CPUDeformer
from rigslim.plugins.deformers.numpy_deformer import NumpyDeformer
from rigslim.plugins.deformers.opencl_deformer import OpenCLDeformer
from rigslim.plugins.deformers.opengl_deformer import OpenGLDeformer


@hookimpl
def rigslim_deformers():
    return [NumpyDeformer(), CPUDeformer(), OpenCLDeformer(), OpenGLDeformer()]
