"""Issue 21 item 2: a reduction that needs no change writes the same deformation.

Files are built by :mod:`support.hostile_gltf`; the reference is the input file's own vertices posed with numpy
(no welding), compared with the output's at times that include ones between the keys.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from support.hostile_gltf import build_gltf, posed_file_positions, random_parts, rigid_parts

from rigslim.commands.cli import main

TIMES = np.linspace(0.0, 1.0, 13)


def _max_displacement(a, b) -> float:
    pa, pb = posed_file_positions(a, TIMES), posed_file_positions(b, TIMES)
    return max(float(np.abs(x - y).max()) for x, y in zip(pa, pb, strict=True))


def _reduce(src, out, k, *extra) -> None:
    assert main(["reduce", str(src), "-o", str(out), "-k", str(k), *extra]) == 0


@pytest.mark.parametrize("weights", ["f32", "u8", "u16"])
def test_three_rigid_parts_with_coincident_corners_come_back_unchanged(tmp_path, weights):
    """Three boxes, each bound to its own joint, touching at coincident corners: welding must not average the
    neighbours' weights onto each other (1.50 % RMS and 32 % max before)."""
    src = build_gltf(tmp_path / "rigid.glb", rigid_parts(3), n_joints=3, weights=weights)
    for k in (1, 2, 4):
        out = tmp_path / f"rigid-k{k}.glb"
        _reduce(src, out, k)
        assert _max_displacement(src, out) == 0.0, f"k = {k}"


def test_separate_meshes_keep_their_own_weights(tmp_path):
    src = build_gltf(tmp_path / "sep.glb", rigid_parts(3), n_joints=4, separate_meshes=True)
    out = tmp_path / "sep-k2.glb"
    _reduce(src, out, 2)
    assert _max_displacement(src, out) == 0.0


@pytest.mark.parametrize("quantize", ["ubyte", "ushort", "float"])
def test_quantisation_adds_no_error_to_float_weights_that_need_no_change(tmp_path, quantize):
    """<= 4 float weights per vertex under -k 4: quantising them to ubyte would add 0.002-0.005 %."""
    parts = random_parts(np.random.default_rng(3), 2, 4, 4)
    src = build_gltf(tmp_path / "float.glb", parts, n_joints=4, weights="f32")
    out = tmp_path / "float-k4.glb"
    _reduce(src, out, 4, "--quantize", quantize)
    assert _max_displacement(src, out) == 0.0


def _property_case(tmp_path, seed, k, n_parts, n_joints, weights) -> float:
    rng = np.random.default_rng(seed)
    parts = random_parts(rng, n_parts, k, n_joints)
    src = build_gltf(tmp_path / f"in-{seed}.glb", parts, n_joints=n_joints, weights=weights)
    out = tmp_path / f"out-{seed}.glb"
    _reduce(src, out, k)
    return _max_displacement(src, out)


CASES = dict(seed=st.integers(0, 2**31 - 1), k=st.integers(1, 4), n_parts=st.integers(1, 3),
             weights=st.sampled_from(["f32", "u8", "u16"]))


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(**CASES, fewer_joints=st.integers(0, 3))
def test_reduce_k_on_a_skin_of_at_most_k_joints_poses_exactly_as_the_input(tmp_path, seed, k, n_parts, weights,
                                                                           fewer_joints):
    """Random parts (coincident corners between neighbours), 1..k influences per vertex, <= k joints:
    ``reduce -k k`` must pose every file vertex exactly as the input in every frame."""
    n_joints = max(1, k - fewer_joints)
    assert _property_case(tmp_path, seed, min(k, 8), n_parts, n_joints, weights) == 0.0


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(**CASES, extra_joints=st.integers(1, 3))
def test_reduce_k_on_at_most_k_influences_poses_exactly_as_the_input(tmp_path, seed, k, n_parts, weights,
                                                                     extra_joints):
    """The same with more joints than k, so that selection and solve run."""
    assert _property_case(tmp_path, seed, k, n_parts, k + extra_joints, weights) == 0.0
