import os

import numpy as np
import pytest

# Ipopt evaluates the model in CasADi's virtual machine in the tests: compiling its NLP costs ~20 s per
# strand structure and the suite solves dozens of structures; test_ipopt_compiled_model checks that the
# compiled model (the default for users) takes the same iterates. Subprocesses inherit it.
os.environ.setdefault("SAGFREE_IPOPT_MODEL", "casadi")


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


@pytest.fixture(scope="session")
def tilted():
    """`horizontal` touching a 5 mm ball at vertex 12, the contact normal tilted 30 degrees towards
    the root: frictionless, the strand slides off sideways (unstable); friction holds it."""
    import sagfree
    from sagfree.bodies import Sphere

    strand = sagfree.scenes.horizontal(n=20)
    return strand, Sphere(strand.points[12] - (0.005 + strand.radius) * np.array([0.5, 0, 0.866]), 0.005)
