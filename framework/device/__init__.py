"""Devices and native libraries, a side leaf: nothing here imports the rest of rigslim but its errors.

- :mod:`~rigslim.device.opencl`: OpenCL contexts, programs and device probing (pyopencl, PoCL on the CPU);
- :mod:`~rigslim.device.egl`: headless OpenGL 3.3 contexts through EGL;
- :mod:`~rigslim.device.native`: native libraries' stderr captured into error messages;
- :mod:`~rigslim.device.numba_threads`: numba's threading layer (a new-enough TBB, or none).

Nothing is imported here: each back end loads its library when first used.
"""
