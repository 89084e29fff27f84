"""OpenCL C and GLSL sources, loaded by name.

Sources live beside this file (``*.cl``, ``*.glsl``) and are read through
:mod:`importlib.resources`, so they work from an installed wheel too.

Example
-------
>>> from rigslim.kernels import source
>>> text = source("some_kernel.cl")  # doctest: +SKIP
"""

from __future__ import annotations

from functools import cache
from importlib import resources


@cache
def source(name: str) -> str:
    """The text of the kernel or shader file ``name`` (e.g. ``"blend.cl"``)."""
    try:
        return resources.files(__name__).joinpath(name).read_text()
    except FileNotFoundError:
        available = sorted(p.name for p in resources.files(__name__).iterdir()
                           if p.name.endswith((".cl", ".glsl")))
        raise FileNotFoundError(f"no kernel source '{name}' in rigslim.kernels; have {available}") from None
