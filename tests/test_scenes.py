"""Reference scenes and the synthetic groom (DESIGN section 8)."""
import numpy as np
import pytest

import sagfree


def test_horizontal_reference_settings():
    s = sagfree.scenes.horizontal()
    assert s.n_vertices == 30 and s.length == pytest.approx(0.10)
    assert (s.radius, s.density, s.youngs_modulus, s.shear_modulus) == (5e-5, 1300.0, 1e9, 4e8)
    assert s.root == "clamped" and np.allclose(s.points[:, 1:], 0) and np.all(np.diff(s.points[:, 0]) > 0)
    f = sagfree.scenes.flipped()
    assert np.allclose(f.points, s.points) and np.allclose(f.theta[1::2], np.pi) and np.allclose(f.theta[::2], 0)


@pytest.mark.parametrize("scene", ["helix", "wavy", "curly"])
def test_curved_scenes_have_equal_edges_and_the_asked_length(scene):
    s = getattr(sagfree.scenes, scene)(n=60)
    e = s.edge_lengths
    assert e.min() / e.max() > 0.95 and s.length == pytest.approx(0.1, rel=0.01)
    assert np.allclose(s.points[0], 0)


def test_helix_geometry():
    s = sagfree.scenes.helix(n=200, coil_radius=0.01, pitch=0.02)
    # a cylinder of the coil radius about the x axis through (y, z) = (0, -R), one pitch per turn
    assert np.allclose(np.linalg.norm(s.points[:, 1:] - [0.0, -0.01], axis=1), 0.01, rtol=1e-12)
    turns = np.unwrap(np.arctan2(s.points[:, 2] + 0.01, s.points[:, 1]))
    assert np.allclose(np.diff(s.points[:, 0]) / np.abs(np.diff(turns)), 0.02 / (2 * np.pi))


def test_groom_is_deterministic_and_varied():
    a, b = sagfree.scenes.groom(30, 40, seed=7), sagfree.scenes.groom(30, 40, seed=7)
    assert all(np.array_equal(x.points, y.points) and x.radius == y.radius for x, y in zip(a, b))
    c = sagfree.scenes.groom(30, 40, seed=8)
    assert not np.array_equal(a[0].points, c[0].points)
    assert all(s.n_vertices == 40 for s in a)
    roots = np.array([s.points[0] for s in a])
    assert np.allclose(np.linalg.norm(roots, axis=1), 0.1)  # rooted on the head sphere
    lengths = [s.length for s in a]
    assert 0.079 < min(lengths) and max(lengths) < 0.161
    turning = [np.abs(sagfree.Problem(s).p0[sagfree.Problem(s).blocks["rest_curvature"]]).max() for s in a[:10]]
    assert max(turning) > 0.05  # wavy and curly strands are curved
