"""Numerics that more than one stage (or the core) uses; each module is one job, named after it.

- :mod:`~rigslim.numerics.blend`: the linear blend ``v' = sum_i a_i T_i [v; 1]`` and blended matrices (the
  numpy reference of every deformer);
- :mod:`~rigslim.numerics.largest_entries`: the k largest entries of each row (influence sets, [P10] section 3);
- :mod:`~rigslim.numerics.small_qp`: batches of small equality- and bound-constrained QPs (the local
  solver's per-vertex solve, docs/algorithms.md section 2);
- :mod:`~rigslim.numerics.area_weighted_normals`: area-weighted vertex normals (the reference normals);
- :mod:`~rigslim.numerics.blended_normals`: normals through the inverse transpose of blended matrices
  (skeletons, docs/algorithms.md section 3);
- :mod:`~rigslim.numerics.affine_normals`: normals through a per-vertex affine fit of the handles
  (cages, [P10] section 5);
- :mod:`~rigslim.numerics.normal_error`: angles between normals and their statistics ([P10] fig. 10);
- :mod:`~rigslim.numerics.surface_distance`: the two-sided Metro distance between surfaces;
- :mod:`~rigslim.numerics.simplex_nnls`: sum-to-one non-negative least squares (the best-fit selector, the
  non-negative geometric solver).
- :mod:`~rigslim.numerics.row_threads`: a nogil numba row kernel over parts of the rows on threads (the
  non-negative geometric solver's per-vertex fits, without a ``prange`` loop's compilation).

Numerics that only one plugin package uses live in that package (the quadrics in
``rigslim.plugins.decimation``, the colourings and the multilevel solver in ``rigslim.plugins.solvers``,
the cage builder in ``rigslim.plugins.generators``).
"""
