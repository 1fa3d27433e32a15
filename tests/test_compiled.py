"""Compiled stencil evaluation agrees with CasADi's virtual machine (the fallback)."""
import numpy as np

from sagfree.formulation.compiled import BatchFunction
from sagfree.formulation.stencils import edge_stencil, vertex_stencil


def test_compiled_and_virtual_machine_agree(rng):
    stencil = vertex_stencil("2d-slerp")
    assert stencil.parameter_jacobian.compiled  # the machine has a C compiler; CI must too
    fallback = BatchFunction(stencil.parameter_jacobian.function)
    args = [rng.standard_normal((7, 11)), rng.standard_normal((7, 13)), rng.uniform(1, 2, (7, 8)),
            rng.standard_normal((7, 7))]
    for a, b in zip(stencil.parameter_jacobian(*args), fallback(*args)):
        assert a.shape == b.shape
        assert np.allclose(a, b, rtol=1e-13, atol=1e-13)
    edge = edge_stencil()
    y = rng.standard_normal((5, 6))
    assert np.allclose(edge.geometry(y)[0], np.linalg.norm(y[:, 3:] - y[:, :3], axis=1), rtol=1e-15)
    assert edge.energy(np.empty((0, 6)), np.empty((0, 2)), np.empty((0, 2)))[0].shape == (0,)
