"""The numpy reference deformer: sparse (or fixed-k) blend of 3x4 handle transforms."""

from __future__ import annotations

import numpy as np

from rigslim.blend import linear_blend
from rigslim.plugin import Deformer


class NumpyDeformer(Deformer):
    name = "numpy"
    summary = "reference linear blend in numpy/scipy (sparse input weights or fixed-k weights)"

    def bind(self, mesh, weights, params):
        V = mesh.V

        def deform(T: np.ndarray) -> np.ndarray:
            return linear_blend(V, weights, T)

        return deform
