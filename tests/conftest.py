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
