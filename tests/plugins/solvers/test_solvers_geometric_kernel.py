"""The compiled non-negative geometric fit agrees with the batched active-set reference (local solver)."""

import numpy as np
import pytest
from support.synthetic import tube_asset

from rigslim.model.asset import Asset
from rigslim.model.mesh import Mesh
from rigslim.numerics.largest_entries import k_largest
from rigslim.plugin import StepContext
from rigslim.plugins.selection.best_fit import best_fit
from rigslim.plugins.solvers.local_solver import local_solve
from rigslim.plugins.solvers.methods import ReductionParams
from rigslim.plugins.solvers.problem import build_problem
from rigslim.plugins.solvers.reduction import solve_weights


def reference(asset):
    prob = build_problem(asset, "geometric", nonnegative=True)
    alpha, rep = local_solve(prob, asset.mesh.adjacency)
    per_vertex = ((np.einsum("mkd,mk->md", prob.B, alpha) - prob.Y) ** 2).sum(axis=1)
    return np.where(asset.influences.valid, alpha, 0.0), rep, prob, per_vertex


def check(asset, atol):
    ctx = StepContext()
    red, rep = solve_weights(asset, "geometric", ReductionParams(), ctx)
    assert rep["backend"] == "numba" and ctx.report["path"] == "local"
    alpha, ref, prob, ref_vertex = reference(asset)
    assert rep["ridge"] == pytest.approx(prob.eps, rel=1e-12)
    assert rep["energy"] == pytest.approx(ref["energy"], rel=1e-9)
    assert rep["energy_start"] == pytest.approx(ref["energy_start"], rel=1e-9)
    np.testing.assert_allclose(red.values, alpha, atol=atol)
    assert (red.values >= 0).all()
    np.testing.assert_allclose(red.values.sum(axis=1), 1.0, atol=1e-12)
    mine = ((np.einsum("mkd,mk->md", prob.B, red.values) - prob.Y) ** 2).sum(axis=1)
    assert (mine <= ref_vertex * (1 + 1e-7) + 1e-9 * prob.Y.var()).all()


def test_tube_k_largest_sets():
    asset = tube_asset()
    asset.influences = k_largest(asset.weights, 2)
    check(asset, 1e-8)


@pytest.mark.parametrize("select", ["k-largest", "best-fit"])
def test_elephant_part(elephant, select):
    m = 1500
    F = elephant.mesh.F[(elephant.mesh.F < m).all(axis=1)]
    asset = Asset(mesh=Mesh(elephant.mesh.V[:m], F), handles=elephant.handles, weights=elephant.weights[:m],
                  poses=elephant.poses, split=elephant.split)
    asset.influences = k_largest(asset.weights, 4) if select == "k-largest" else best_fit(asset, 4, "error")[0]
    # Nearly flat directions (bones that move alike) let the weights differ by ~1e-5 at equal energy.
    check(asset, 1e-4)


def test_other_settings_keep_the_general_path():
    asset = tube_asset()
    asset.influences = k_largest(asset.weights, 2)
    for params in (ReductionParams(nonnegative=False), ReductionParams(solver="global", nonnegative=False)):
        _, rep = solve_weights(asset, "geometric", params)
        assert rep.get("backend") != "numba"
