"""Numerics that more than one stage uses.

- :mod:`rigslim.numerics.k_largest`: the k largest entries of each row (influence sets, [P10] section 3);
- :mod:`rigslim.numerics.small_qp`: batches of small equality- and bound-constrained QPs (the local
  solver's per-vertex solve, docs/algorithms.md section 2).

Numerics that only one plugin package uses live in that package.
"""
