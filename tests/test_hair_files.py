"""Hair files: cyHair .hair, USC-HairSalon .data and OBJ polylines (scenes.cyhair, usc_data,
obj_polylines): round trips, units, material, and errors that name the file and the strand or line."""
import re

import numpy as np
import pytest

import sagfree
from sagfree.scenes.cyhair import HEADER, load_hair, save_hair
from sagfree.scenes.obj_polylines import load_obj, save_obj
from sagfree.scenes.synthetic import MATERIAL
from sagfree.scenes.usc_data import load_data, save_data

FORMATS = {"hair": (save_hair, load_hair), "data": (save_data, load_data), "obj": (save_obj, load_obj)}
FLOAT32 = 1e-7  # relative precision of the binary formats


def strands():
    """Strands of different vertex counts and radii."""
    return sagfree.scenes.groom(5, 20, seed=1)[:3] + [sagfree.scenes.horizontal(n=7),
                                                      sagfree.scenes.curly(n=11)]


def assert_points_close(back, strands, rel):
    """Same vertex counts; points equal to ``rel`` times the largest coordinate of the strand."""
    assert [b.n_vertices for b in back] == [s.n_vertices for s in strands]
    for a, b in zip(strands, back):
        np.testing.assert_allclose(b.points, a.points, rtol=0, atol=rel * np.abs(a.points).max())


def fails(where, message):
    """pytest.raises(ValueError) for a message "{where}: {message}" (``message`` a regex)."""
    return pytest.raises(ValueError, match="^" + re.escape(f"{where}: ") + message)


def hair_bytes(counts, flags=0b11, default_segments=0, default_thickness=0.0, thickness=None):
    """A hand-made cyHair file: strand k along x at y = k, vertices 1 unit apart."""
    header = np.zeros(1, HEADER)
    header[0] = (b"HAIR", len(counts), sum(counts), flags, default_segments, default_thickness, 0.0,
                 (0, 0, 0), b"test")
    points = np.concatenate([np.c_[np.arange(c), np.full(c, k), np.zeros(c)]
                             for k, c in enumerate(counts)])
    parts = [header.tobytes()]
    if flags & 1:
        parts.append((np.array(counts) - 1).astype("<u2").tobytes())
    parts.append(points.astype("<f4").tobytes())
    if thickness is not None:
        parts.append(np.asarray(thickness, "<f4").tobytes())
    return b"".join(parts)


def data_bytes(counts):
    """A hand-made .data file: strands of ``counts`` vertices along x, 1 unit apart."""
    parts = [np.array([len(counts)], "<i4").tobytes()]
    for c in counts:
        parts += [np.array([c], "<i4").tobytes(),
                  np.c_[np.arange(c), np.zeros((c, 2))].astype("<f4").tobytes()]
    return b"".join(parts)


# --- round trips and units -------------------------------------------------------------------------

@pytest.mark.parametrize("fmt", FORMATS)
def test_round_trip(tmp_path, fmt):
    save, load = FORMATS[fmt]
    original = strands()
    save(tmp_path / f"s.{fmt}", original)
    assert_points_close(load(tmp_path / f"s.{fmt}"), original, 0.0 if fmt == "obj" else FLOAT32)


@pytest.mark.parametrize("fmt", FORMATS)
def test_units(tmp_path, fmt):
    save, load = FORMATS[fmt]
    path, original = tmp_path / f"s.{fmt}", strands()
    save(path, original, units="cm")
    in_cm = load(path, units="cm")
    assert_points_close(in_cm, original, 1e-15 if fmt == "obj" else FLOAT32)
    for a, b, c in zip(in_cm, load(path, units="m"), load(path, units="mm")):
        np.testing.assert_allclose(b.points, 100 * a.points, rtol=1e-14, atol=1e-14)
        np.testing.assert_allclose(c.points, a.points / 10, rtol=1e-14, atol=1e-14)
    with pytest.raises(ValueError, match="units must be one of m, cm, mm, got 'inch'"):
        load(path, units="inch")


def test_cyhair_default_units_are_cm(tmp_path):
    save_hair(tmp_path / "s.hair", strands())
    raw = np.frombuffer((tmp_path / "s.hair").read_bytes(), "<f4", count=3,
                        offset=HEADER.itemsize + 2 * 5)  # after the header and 5 segment counts
    np.testing.assert_allclose(raw, 100 * strands()[0].points[0], rtol=FLOAT32)


def test_cyhair_default_segments_without_segments_array(tmp_path):
    (tmp_path / "s.hair").write_bytes(hair_bytes([5, 5, 5], flags=0b10, default_segments=4))
    back = load_hair(tmp_path / "s.hair", units="m")
    assert [s.n_vertices for s in back] == [5, 5, 5]
    np.testing.assert_array_equal(back[2].points[:, 1], 2.0)


# --- material ---------------------------------------------------------------------------------------

def test_cyhair_radius_from_thickness(tmp_path):
    original = strands()
    save_hair(tmp_path / "s.hair", original, units="mm")
    back = load_hair(tmp_path / "s.hair", units="mm")
    np.testing.assert_allclose([b.radius for b in back], [s.radius for s in original], rtol=FLOAT32)
    # thickness array (diameters, cm): half the mean over the strand's points
    (tmp_path / "t.hair").write_bytes(hair_bytes([3, 4], flags=0b111,
                                                 thickness=[0.01, 0.02, 0.03] + [0.004] * 4))
    assert [s.radius for s in load_hair(tmp_path / "t.hair")] == pytest.approx([1e-4, 2e-5], rel=1e-6)
    # no thickness array: half the default thickness if positive, else MATERIAL
    (tmp_path / "d.hair").write_bytes(hair_bytes([3, 4], default_thickness=0.008))
    assert [s.radius for s in load_hair(tmp_path / "d.hair")] == pytest.approx([4e-5, 4e-5], rel=1e-6)
    (tmp_path / "n.hair").write_bytes(hair_bytes([3, 4]))
    assert [s.radius for s in load_hair(tmp_path / "n.hair")] == [MATERIAL["radius"]] * 2


@pytest.mark.parametrize("fmt", FORMATS)
def test_material_defaults_and_overrides(tmp_path, fmt):
    save, load = FORMATS[fmt]
    path = tmp_path / f"s.{fmt}"
    save(path, strands())
    s = load(path)[3]
    assert (s.youngs_modulus, s.shear_modulus, s.density) == \
           (MATERIAL["youngs_modulus"], MATERIAL["shear_modulus"], MATERIAL["density"])
    if fmt != "hair":  # no radius in the file
        assert s.radius == MATERIAL["radius"]
    override = {"radius": 8e-5, "youngs_modulus": 3e9, "shear_modulus": 1e9, "density": 1100.0}
    for s in load(path, **override):
        assert (s.radius, s.youngs_modulus, s.shear_modulus, s.density) == tuple(override.values())
    with pytest.raises(TypeError, match="unknown material keyword"):
        load(path, stiffness=1.0)


# --- cyHair errors ----------------------------------------------------------------------------------

def test_cyhair_truncated(tmp_path):
    path = tmp_path / "s.hair"
    save_hair(path, strands())
    path.write_bytes(path.read_bytes()[:-10])  # cuts into the last strand's thickness values
    with fails(path, "strand 4: truncated file .* thickness array"):
        load_hair(path)
    path.write_bytes(hair_bytes([3, 4, 5])[:HEADER.itemsize + 6 + 12 * 4])  # inside strand 1's points
    with fails(path, "strand 1: truncated file .* points array"):
        load_hair(path)
    path.write_bytes(b"HAIR" + bytes(20))
    with fails(path, "truncated file: 24 bytes, shorter than the 128-byte cyHair header"):
        load_hair(path)


def test_cyhair_bad_header_and_trailing_data(tmp_path):
    path = tmp_path / "s.hair"
    path.write_bytes(b"RIAH" + hair_bytes([3, 4])[4:])
    with fails(path, "not a cyHair file: signature b'RIAH'"):
        load_hair(path)
    data = bytearray(hair_bytes([3, 4]))
    data[8:12] = np.array([8], "<u4").tobytes()  # the header claims 8 points, the strands hold 7
    path.write_bytes(bytes(data))
    with fails(path, "point count mismatch: .* 7 points .* says 8"):
        load_hair(path)
    path.write_bytes(hair_bytes([3, 4], flags=0b01))
    with fails(path, "the header flags 0x1 announce no points array"):
        load_hair(path)
    path.write_bytes(hair_bytes([3, 4]) + b"\0\0")
    with fails(path, "2 bytes of trailing data .* strand 1"):
        load_hair(path)


def test_cyhair_short_and_invalid_strands(tmp_path):
    path = tmp_path / "s.hair"
    path.write_bytes(hair_bytes([3, 2, 4]))
    with fails(path, "strand 1: a strand needs at least 3 vertices, got 2"):
        load_hair(path)
    path.write_bytes(hair_bytes([3, 4], flags=0b111, thickness=[0.01] * 3 + [0.0] * 4))
    with fails(path, "strand 1: radius must be positive"):
        load_hair(path)


# --- .data errors -----------------------------------------------------------------------------------

def test_data_truncated_negative_and_trailing(tmp_path):
    path = tmp_path / "s.data"
    path.write_bytes(data_bytes([3, 4, 5])[:-1])
    with fails(path, "strand 2: truncated file: 5 vertices need 60 bytes, 59 are left"):
        load_data(path)
    path.write_bytes(np.array([3], "<i4").tobytes() + data_bytes([3, 4])[4:])
    with fails(path, "strand 2: truncated file: .* before the vertex count"):
        load_data(path)
    path.write_bytes(data_bytes([3, 4]) + b"\1\0")
    with fails(path, "2 bytes of trailing data after strand 1"):
        load_data(path)
    data = bytearray(data_bytes([3, 4]))
    data[44:48] = np.array([-4], "<i4").tobytes()  # strand 1's count: after 4 + (4 + 3 * 12) bytes
    path.write_bytes(bytes(data))
    with fails(path, "strand 1: negative vertex count -4"):
        load_data(path)
    path.write_bytes(np.array([-1], "<i4").tobytes())
    with fails(path, "negative strand count -1"):
        load_data(path)


def test_data_short_strands(tmp_path):
    path = tmp_path / "s.data"
    path.write_bytes(data_bytes([4, 1, 5, 0, 2, 3]))
    with fails(path, "strand 1: a strand needs at least 3 vertices, got 1 .* skip_short=True"):
        load_data(path)
    assert [s.n_vertices for s in load_data(path, skip_short=True)] == [4, 5, 3]
    path.write_bytes(data_bytes([2, 3])[:-12] + np.zeros(3, "<f4").tobytes())  # strand 1 folds back
    with fails(path, "strand 1: vertex 1 turns by 180.0 degrees"):  # numbered as in the file
        load_data(path, skip_short=True)


# --- OBJ --------------------------------------------------------------------------------------------

def test_obj_syntax(tmp_path):
    """Comments and other statements ignored, i/t pairs, negative indices, chained 2-vertex segments."""
    path = tmp_path / "s.obj"
    path.write_text("# a comment\no hair\nv 0 0 0\nv 1 0 0 1.0\nvt 0.5 0.5\nv 2 0 0 # third\n"
                    "vn 0 0 1\nl 1 2/1 3\nv 0 1 0\nv 1 1 0\nv 2 1 0\nv 3 1 0\nl -4 -3 -2 -1\n"
                    "f 1 2 3\ng strand2\nv 0 2 0\nv 1 2 0\nv 2 2 0\nl 8 9\nl 9 10\nl 3 2 1\n")
    back = load_obj(path, units="cm")
    assert [s.n_vertices for s in back] == [3, 4, 3, 3]
    np.testing.assert_allclose(back[1].points, [[0, 0.01, 0], [0.01, 0.01, 0], [0.02, 0.01, 0],
                                                [0.03, 0.01, 0]])
    np.testing.assert_allclose(back[2].points, [[0, 0.02, 0], [0.01, 0.02, 0], [0.02, 0.02, 0]])
    np.testing.assert_allclose(back[3].points[0], [0.02, 0, 0])


@pytest.mark.parametrize("body, line, message", [
    ("l 1 2 5\n", 5, "vertex index 5 out of range: the file has 4 vertices"),
    ("l 0 1 2\n", 5, "vertex index 0: OBJ indices start at 1"),
    ("l 1 -5 2\n", 5, "vertex index -5 out of range: only 4 vertices precede it"),
    ("l 1 two 3\n", 5, "bad vertex index 'two'"),
    ("v 1 2\n", 5, "bad vertex 'v 1 2', expected 'v x y z'"),
    ("l 1 2 3\n\nl 3 4\n", 7, "strand 1: a strand needs at least 3 vertices, got 2"),
    ("l 1 2 3\nl 3 2 4\n", 6, "strand 1: vertex 1 turns by 180.0 degrees"),
])
def test_obj_errors(tmp_path, body, line, message):
    path = tmp_path / "s.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nv 3 0 0\n" + body)
    with fails(f"{path}:{line}", message):
        load_obj(path)
