"""Banded linear algebra on plain arrays: the one place for the solvers, the simulation and the
eigenvalue code (DESIGN section 2).

Every strand matrix is banded because DOFs and parameters are both ordered along the strand:

- ``band``: bordered band storage of symmetric matrices, products, J^T J accumulated from J,
  principal submatrices of a band (the free DOFs);
- ``cholesky``: the banded Cholesky factorization and its solves, with an active set (the
  rows and columns of bound variables replaced by the identity) and partial refactorization;
- ``normal``: the row-space normal matrix J_C diag(d) J_C^T, factored (least-squares multipliers);
- ``saddle``: the equality-constrained step [[W_F, J_F^T], [J_F, 0]], by band LU;
- ``eigen``: the smallest eigenvalue of a band matrix by shift-and-invert Lanczos.
- ``identity``: values remembered by the identity of the (shared) index arrays they came from.

A sparse argument ``J`` is a scipy.sparse matrix or any object with ``shape`` and the methods
``csr()`` / ``csc()`` returning (indptr, indices, data) (formulation.jacobian.StrandJacobian gives
them without conversion); nothing here knows about strands.
"""
