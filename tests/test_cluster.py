"""The batch on a Dask LocalCluster gives the local run's results, failures isolated."""
import numpy as np
import pytest

import sagfree
from sagfree.cli import main

pytest.importorskip("distributed")


def test_local_cluster_matches_the_local_run_and_isolates_a_poisoned_strand(tmp_path, capsys):
    strands = sagfree.scenes.groom(5, 16, seed=6)
    local = sagfree.optimize(strands, jobs=1)
    batch = [*strands[:2], "not a strand", *strands[2:]]
    distributed = sagfree.optimize(batch, jobs=2, scheduler="local")
    assert distributed[2].status == "failed" and "invalid strand" in distributed[2].message
    others = distributed[:2] + distributed[3:]
    for a, b in zip(local, others):
        assert a.status == b.status == "converged"
        np.testing.assert_array_equal(a.p, b.p)
    sagfree.save(tmp_path / "s.npz", strands[:2])
    assert main(["optimize", str(tmp_path / "s.npz"), "-o", str(tmp_path / "p.npz"), "--scheduler", "local",
                 "--jobs", "2", "--quiet"]) == 0
    params = np.load(tmp_path / "p.npz")
    np.testing.assert_array_equal(params["p"], np.concatenate([r.p for r in local[:2]]))
