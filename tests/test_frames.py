"""Reference frames: Bishop construction, time-parallel transport and the reference twist."""
import numpy as np

import sagfree
from sagfree.formulation import frames as fr


def random_curve(rng, n=20):
    steps = rng.standard_normal((n - 1, 3)) + [2.0, 0, 0]
    return np.vstack([np.zeros(3), np.cumsum(steps * 1e-3, axis=0)])


def assert_orthonormal(f: fr.Frames):
    assert np.allclose(np.linalg.norm(f.a1, axis=1), 1, atol=1e-14)
    assert np.allclose(np.sum(f.a1 * f.tangents, axis=1), 0, atol=1e-14)
    assert np.allclose(np.linalg.norm(f.a2, axis=1), 1, atol=1e-14)


def test_bishop_frames_are_parallel_transported(rng):
    x = random_curve(rng)
    t = fr.unit(fr.edges(x))
    f = fr.bishop_frames(x, fr.default_director(t[0], np.array([0, 0, -9.81])))
    assert_orthonormal(f)
    # each director is the previous one transported: the reference twist of the Bishop frame is 0
    assert np.allclose(fr.reference_twist(f.tangents, f.a1, np.zeros(len(x) - 2)), 0, atol=1e-13)
    # the default director is "up" projected perpendicular to the first edge
    up = np.array([0, 0, 1.0]) - t[0, 2] * t[0]
    assert np.allclose(f.a1[0], up / np.linalg.norm(up))


def test_default_director_falls_back_when_first_edge_is_vertical():
    a1 = fr.default_director(np.array([0, 0, -1.0]), np.array([0, 0, -9.81]))
    assert np.allclose(a1, [1, 0, 0])


def test_transport_to_same_shape_is_identity_and_twist_accumulates(rng):
    x = random_curve(rng)
    f = fr.bishop_frames(x, fr.default_director(fr.unit(x[1] - x[0]), np.array([0, 0, -1.0])))
    same = fr.transport_frames(f, x)
    assert np.allclose(same.a1, f.a1, atol=1e-15) and np.allclose(same.reference_twist, 0, atol=1e-13)
    # move along a smooth path to a strongly coiled shape in small steps: frames stay orthonormal,
    # the reference twist changes continuously and agrees modulo 2 pi with the direct angle
    coil = np.column_stack([0 * x[:, 0], 3e-3 * np.sin(4 * x[:, 0] / 1e-2), 3e-3 * np.cos(4 * x[:, 0] / 1e-2)])
    current = f
    for k in range(1, 41):
        nxt = fr.transport_frames(current, x + (k / 40) * (coil - coil[0]))
        assert_orthonormal(nxt)
        assert np.all(np.abs(nxt.reference_twist - current.reference_twist) < 0.3)
        # the compiled update is the readable formula of reference_twist
        assert np.allclose(nxt.reference_twist, fr.reference_twist(nxt.tangents, nxt.a1, current.reference_twist),
                           rtol=0, atol=1e-12)
        direct = fr.signed_angle(fr.parallel_transport(nxt.tangents[:-1], nxt.tangents[1:], nxt.a1[:-1]),
                                 nxt.a1[1:], nxt.tangents[1:])
        assert np.allclose(np.angle(np.exp(1j * (nxt.reference_twist - direct))), 0, atol=1e-10)
        current = nxt
    assert np.abs(current.reference_twist).max() > 0.1


def test_material_frames_of_flipped_edges_are_reversed():
    s = sagfree.scenes.flipped(n=6)
    pb = sagfree.Problem(s)
    d1, d2 = fr.material_frames(pb.frames, s.theta)
    assert np.allclose(d1[1], -d1[0]) and np.allclose(d2[1], -d2[0])
