"""Solver plugins geometric, smooth, poisson: invariants, k = n, parameters, pipelines."""

import json

import numpy as np
import pytest
from support.synthetic import cage_asset, tube_asset

from rigslim.errors import RigslimError, StepError
from rigslim.numerics.largest_entries import k_largest
from rigslim.plugins.solvers.methods import LaplacianParams, PoissonParams, ReductionParams
from rigslim.plugins.solvers.reduction import solve_weights
from rigslim.runtime.run import run_pipeline

PARAMS = {"geometric": ReductionParams, "smooth": LaplacianParams, "poisson": PoissonParams}


def _check_invariants(red, k, nonneg):
    assert red.k == k and (red.influence_counts() <= k).all()
    np.testing.assert_allclose(red.values.sum(axis=1), 1.0, atol=1e-6)
    if nonneg:
        assert (red.values >= 0).all()


@pytest.mark.parametrize("method", ["geometric", "smooth", "poisson"])
@pytest.mark.parametrize("solver", ["auto", "local", "global"])
def test_invariants_tube(method, solver):
    asset = tube_asset()
    asset.influences = k_largest(asset.weights, 2)
    nonneg = solver != "global"
    params = PARAMS[method](solver=solver, nonnegative=nonneg, max_sweeps=50)
    red, rep = solve_weights(asset, method, params)
    _check_invariants(red, 2, nonneg)
    assert rep["method"] == method and rep["energy"] <= rep.get("energy_start", np.inf) + 1e-9


@pytest.mark.parametrize("method", ["geometric", "smooth", "poisson"])
def test_invariants_cage_negative_allowed(method):
    asset = cage_asset()
    asset.influences = k_largest(asset.weights, 4)
    red, rep = solve_weights(asset, method, PARAMS[method](nonnegative=False))
    _check_invariants(red, 4, False)
    assert rep["path"] == "global" and rep["gap"] == 0.0


@pytest.mark.parametrize("method", ["geometric", "smooth", "poisson"])
def test_k_equal_n_returns_input(method):
    for asset, n in ((tube_asset(), 4), (cage_asset(), 8)):
        asset.influences = k_largest(asset.weights, n)
        for nonneg in (False, True):
            red, _ = solve_weights(asset, method, PARAMS[method](nonnegative=nonneg))
            np.testing.assert_allclose(red.to_sparse().toarray(), asset.weights.toarray(), atol=1e-6)


def test_default_nonnegative_rule():
    tube = tube_asset()
    tube.influences = k_largest(tube.weights, 2)
    assert solve_weights(tube, "poisson", PoissonParams(max_sweeps=5))[1]["nonnegative"] is True
    cage = cage_asset()  # mean value coordinates in a convex cage: all positive
    cage.influences = k_largest(cage.weights, 4)
    assert solve_weights(cage, "poisson", PoissonParams(max_sweeps=5))[1]["nonnegative"] is True
    cage.weights.data[0] = -abs(cage.weights.data[0])  # one negative input weight: default off
    assert solve_weights(cage, "poisson", PoissonParams(max_sweeps=5))[1]["nonnegative"] is False


def test_geometric_is_per_vertex_optimal_with_nonnegativity(elephant):
    from scipy.optimize import nnls

    from rigslim.plugins.solvers.problem import build_problem

    elephant.influences = k_largest(elephant.weights, 4)
    red, rep = solve_weights(elephant, "geometric", ReductionParams())
    prob = build_problem(elephant, "geometric")
    def per_vertex(a):
        return ((np.einsum("mkd,mk->md", prob.B, a) - prob.Y) ** 2).sum(axis=1)
    e = per_vertex(red.values)
    # Any feasible point is no better, e.g. normalised NNLS fits and the k-largest weights.
    rows = np.arange(0, prob.m, 97)
    alt = np.array([nnls(prob.B[v].T, prob.Y[v])[0] for v in rows])
    alt /= alt.sum(axis=1, keepdims=True)
    alt_full = red.values.copy()
    alt_full[rows] = alt
    assert (e[rows] <= per_vertex(alt_full)[rows] + 1e-6).all()
    assert (e <= per_vertex(prob.alpha0) + 1e-6).all()


def test_smooth_on_cage_needs_linear_precision():
    asset = cage_asset()
    asset.influences = k_largest(asset.weights, 4)
    with pytest.raises(StepError, match="linear precision"):
        solve_weights(asset, "smooth", LaplacianParams(linear_precision=False))


def test_global_with_nonnegative_is_an_error():
    asset = tube_asset()
    asset.influences = k_largest(asset.weights, 2)
    with pytest.raises(StepError) as err:
        solve_weights(asset, "poisson", PoissonParams(solver="global", nonnegative=True))
    assert err.value.field == "solver" and "auto" in err.value.fix


def test_position_weight_lowers_position_error_on_examples():
    from rigslim.numerics.blend import linear_blend

    asset = tube_asset()
    asset.influences = k_largest(asset.weights, 2)
    T = asset.example_poses().T
    def err(red):
        return sum(np.sum((linear_blend(asset.mesh.V, red, t) - linear_blend(asset.mesh.V, asset.weights, t)) ** 2)
                   for t in T)
    e0 = err(solve_weights(asset, "poisson", PoissonParams(nonnegative=False))[0])
    e1 = err(solve_weights(asset, "poisson", PoissonParams(nonnegative=False, position_weight=10.0))[0])
    assert e1 < e0


PIPE = """
inputs:
  mesh: data/elephant.obj
  skeleton: data/elephant.tgf
  weights: data/elephant-weights.dmat
  animation: data/elephant-anim.dmat
poses: {{examples: "0:457:45", test: "5:457:7"}}
steps:
  - select: k-largest
    k: 4
  - solve: {method}
{params}
  - evaluate: [position-rms, normal-deviation, max-influences]
"""


@pytest.mark.parametrize("method,params", [
    ("geometric", ""),
    ("smooth", "    laplacian: plain\n    max_sweeps: 3"),
    ("poisson", "    solver: local\n    max_sweeps: 3\n    position_weight: 0.01"),
    ("poisson", "    solver: global\n    nonnegative: false"),
])
def test_pipeline_yaml(write_pipeline, tmp_path, method, params):
    path = write_pipeline(PIPE.format(method=method, params=params))
    res = run_pipeline(path, metrics_path=tmp_path / "m.json", console=None)
    doc = json.loads((tmp_path / "m.json").read_text())
    step = next(s for s in doc["steps"] if s["stage"] == "solve")
    assert step["solver"]["method"] == method
    assert {"energy", "path"} <= set(step["solver"])
    assert res.asset.reduced.k == 4
    assert doc["metrics"]["max_influences"] <= 4 if "metrics" in doc else True


def test_bad_parameter_is_a_one_line_error(write_pipeline):
    path = write_pipeline(PIPE.format(method="poisson", params="    laplacian: cubic"))
    with pytest.raises(RigslimError) as err:
        run_pipeline(path, console=None)
    assert "\n" not in str(err.value)


def test_auto_uses_amg_cg_above_limit():
    asset = tube_asset()
    asset.influences = k_largest(asset.weights, 2)
    _, direct = solve_weights(asset, "poisson", PoissonParams(nonnegative=False))
    red, rep = solve_weights(asset, "poisson", PoissonParams(global_max_unknowns=10, nonnegative=False,
                                                              residual_tolerance=1e-9))
    assert direct["path"] == "global" and rep["path"] == "global: amg-cg" and rep["iterations"] >= 1
    assert rep["converged"] and rep["kkt_residual"] <= 1e-9
    assert abs(rep["energy"] - direct["energy"]) <= 1e-6 * abs(direct["energy"])
    _check_invariants(red, 2, False)


def test_auto_nonnegative_above_limit_reports_kkt():
    asset = tube_asset()
    asset.influences = k_largest(asset.weights, 2)
    red, rep = solve_weights(asset, "poisson", PoissonParams(global_max_unknowns=10, nonnegative=True))
    assert rep["path"] == "auto: amg-cg, projection, local"
    assert rep["energy"] >= rep["equality_optimum"] * (1 - 1e-9)
    assert 0 <= rep["kkt_residual"] < 1e-5
    _check_invariants(red, 2, True)


@pytest.mark.parametrize("solve", ["smooth", "poisson"])
def test_a_rigid_rig_whose_equality_optimum_is_zero(solve):
    """Every vertex bound to one bone (a BVH/CSM conversion): the equality optimum's energy is exactly 0, and
    its relative gap once divided by it (ZeroDivisionError). The weights pass through, the gap is absolute."""
    import rigslim

    rng = np.random.default_rng(0)
    V = rng.random((30, 3))
    F = np.array([[i, i + 1, i + 2] for i in range(28)])
    W = np.zeros((30, 3))
    W[np.arange(30), np.arange(30) % 3] = 1.0
    T = np.tile(np.eye(3, 4), (4, 3, 1, 1))
    T[:, :, :, 3] = rng.random((4, 3, 3))
    report: dict = {}
    out = rigslim.reduce_weights((V, F), W, T, k=2, select="k-largest", solve=solve, report=report)
    np.testing.assert_allclose(out.to_sparse().toarray(), W, atol=1e-12)
