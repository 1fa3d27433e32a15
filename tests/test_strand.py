"""Strand validation: every bad input names what is wrong and where."""
import numpy as np
import pytest

import sagfree


def line(n=5):
    x = np.linspace(0, 0.1, n)
    return np.column_stack([x, 0 * x, 0 * x])


@pytest.mark.parametrize("edit, message", [
    (lambda p: p[:2], "at least 3 vertices"),
    (lambda p: np.where(np.arange(5)[:, None] == 3, np.nan, p), "vertex 3 has a non-finite"),
    (lambda p: np.insert(p, 2, p[2], axis=0), "edge 2 (vertices 2 and 3) has zero length"),
    (lambda p: np.vstack([p[:3], p[1:2] + [1e-4, 1e-6, 0]]), "vertex 2 turns by"),
    (lambda p: p[:, :2], "shape (n, 3)"),
])
def test_bad_points_are_named(edit, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        sagfree.Strand(edit(line()))


@pytest.mark.parametrize("kwargs, message", [
    (dict(radius=0), "radius"), (dict(radius=-1e-5), "radius"), (dict(youngs_modulus=np.inf), "youngs"),
    (dict(shear_modulus=0), "shear"), (dict(density=-1), "density"), (dict(root="free"), "root"),
    (dict(theta=np.zeros(3)), "one angle per edge"), (dict(theta=[0, 0, np.nan, 0]), "theta of edge 2"),
    (dict(director=[1, 2]), "director"),
])
def test_bad_material_and_options(kwargs, message):
    with pytest.raises(ValueError, match=message):
        sagfree.Strand(line(), **kwargs)


def test_director_parallel_to_first_edge_is_an_error():
    with pytest.raises(ValueError, match="parallel to the first edge"):
        sagfree.Problem(sagfree.Strand(line(), director=[2.0, 0, 0]))


def test_lumped_masses_sum_to_strand_mass():
    s = sagfree.Strand(line(7), radius=3e-5, density=1100.0)
    assert s.vertex_masses.sum() == pytest.approx(1100.0 * np.pi * 3e-5**2 * 0.1, rel=1e-12)
    assert s.length == pytest.approx(0.1)


def test_a_radius_far_above_the_edge_lengths_is_refused_naming_the_edge():
    """A 1 mm, 50-vertex strand with a 5 mm radius (a unit mix-up) is not a thin rod; a 2000-vertex
    hair whose radius is 1.4 edge lengths is kept."""
    x = np.linspace(0.0, 1e-3, 50)
    points = np.column_stack([x, 0 * x, 1e-4 * np.sin(3000 * x)])
    with pytest.raises(ValueError, match=r"radius 0.005 m is .* times the length of edge \d+ .*not a thin rod"):
        sagfree.Strand(points, radius=5e-3)
    assert sagfree.Strand(points, radius=2e-5).radius == 2e-5
    hair = sagfree.scenes.groom(1, 2000, seed=0)[0]
    assert hair.radius > hair.edge_lengths.min()


def test_a_batch_warns_once_naming_the_strands_thicker_than_an_edge():
    """Radii of one to ten edge lengths are solved, with one warning naming strand and edge."""
    x = np.linspace(0.0, 1e-3, 30)
    thick = sagfree.Strand(np.column_stack([x, 0 * x, 0 * x]), radius=5e-5)  # 1.45 edge lengths
    with pytest.warns(UserWarning, match=r"1 of 2 strands have a radius above an edge length \(strand 1 at edge"):
        results = sagfree.optimize([sagfree.scenes.horizontal(), thick], jobs=1)
    assert [r.status for r in results] == ["converged", "converged"]


def test_the_compiled_thickness_is_numpys():
    """radius_per_edge's compiled pass gives numpy's (argmin of the edge norms: the first shortest
    edge, a NaN length taken as the minimum) bit for bit."""
    from sagfree.formulation.strand import radius_per_edge
    rng = np.random.default_rng(0)
    cases = [rng.standard_normal((k, 3)) for k in (2, 3, 10, 100)]
    tied = rng.standard_normal((10, 3))
    tied[4], tied[7] = tied[3], tied[6]  # two zero-length edges: the first is named
    holed = rng.standard_normal((10, 3))
    holed[6, 1] = np.nan
    for points in cases + [tied, holed]:
        lengths = np.linalg.norm(np.diff(points, axis=0), axis=1)
        edge = int(np.argmin(lengths))
        with np.errstate(all="ignore"):
            for radius in (1e-4, 5.0):
                found = radius_per_edge(points, radius)
                assert found[0] == edge
                assert found[1] == radius / lengths[edge] or np.isnan(found[1]) and np.isnan(lengths[edge])


def test_root_held_is_attached_without_its_holds_and_shares_the_validated_arrays():
    strand = sagfree.Strand(np.cumsum(np.full((6, 3), 0.01), axis=0), tip="pinned", pins=[2], loads=np.ones((6, 3)))
    twin, checked = strand.root_held(), strand.attached(tip="free", pins=())
    assert twin.tip is None and twin.pins.size == 0 and twin.root == strand.root
    assert twin.attachments == checked.attachments
    for name in ("points", "theta", "loads"):
        assert np.array_equal(getattr(twin, name), getattr(checked, name))
    assert twin.points is strand.points and strand.tip == "pinned" and strand.pins.tolist() == [2]
