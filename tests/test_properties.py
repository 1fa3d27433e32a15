"""Property-based tests (hypothesis): random and corrupted inputs never crash the strand file readers,
``Strand`` or ``Problem``. Each call either succeeds or raises ValueError with a non-empty message;
any other exception type is a bug.

The bugs these properties found (a cyHair header demanding 16 GiB, OverflowError and NaN residuals
from extreme material values) are fixed; each keeps an explicit ``@example`` that triggered it, tried
before any generated input.

Every reader call runs under an address-space limit (``memory_guard``): a corrupted header must not be
able to make a reader allocate many GiB (it turns such an allocation into a MemoryError instead of
swapping or OOM-killing the test run).
"""
from __future__ import annotations

import contextlib
import itertools
import os
import struct
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

import sagfree
from sagfree.formulation.strand import InvalidStrand, Strand
from sagfree.scenes.cyhair import load_hair, save_hair
from sagfree.scenes.npz import load_strands, save_strands
from sagfree.scenes.obj_polylines import load_obj, save_obj
from sagfree.scenes.usc_data import load_data, save_data

# ---------------------------------------------------------------------------------------------------
# shared helpers
# ---------------------------------------------------------------------------------------------------

#: extension -> (writer, reader); readers take keep_invalid, writers (path, strands).
FORMATS = {
    "hair": (save_hair, load_hair),
    "data": (save_data, load_data),
    "obj": (save_obj, load_obj),
    "npz": (save_strands, load_strands),
}

#: A 128-byte cyHair header announcing 2**31 strands and no segments array (flags = points only):
#: load_hair builds np.full(2**31, ...) (16 GiB) before checking the counts against the file size.
HUGE_HAIR_HEADER = struct.pack("<4sIIII", b"HAIR", 2**31, 0, 0b10, 0) + bytes(128 - 20)
#: The same defect as a 12-byte overwrite at offset 4 of a valid .hair file (strands, points, flags).
HUGE_HAIR_PATCH = struct.pack("<III", 2**31, 0, 0b10)

_counter = itertools.count()

#: Common hypothesis settings: no deadline (Problem compiles C code on first use), no example database
#: (deterministic runs, nothing written next to the checkout).
SETTINGS = dict(deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow])


@contextlib.contextmanager
def memory_guard(extra_bytes: int = 2 << 30):
    """Limit the address space to the current size + ``extra_bytes`` while the block runs."""
    try:
        import resource

        with open("/proc/self/statm") as f:
            current = int(f.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
    except (ImportError, OSError, ValueError):
        pytest.skip("no address-space limit available here; a corrupted header could exhaust memory")
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    limit = current + extra_bytes
    if hard != resource.RLIM_INFINITY:
        limit = min(limit, hard)
    if soft != resource.RLIM_INFINITY:
        limit = min(limit, soft)
    resource.setrlimit(resource.RLIMIT_AS, (limit, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))


def write_file(directory, ext: str, data: bytes):
    path = directory / f"fuzz_{next(_counter)}.{ext}"
    path.write_bytes(data)
    return path


def check_reader(ext: str, path, keep_invalid: bool):
    """Read ``path``: a list of strands (InvalidStrand allowed with keep_invalid) or a ValueError with
    a message; a warning (an implausible radius from a corrupted thickness) must name the file. Any
    other exception propagates and fails the test. Returns the list or None."""
    reader = FORMATS[ext][1]
    try:
        with memory_guard(), warnings.catch_warnings(record=True) as warned:
            warnings.simplefilter("always")
            out = reader(path, keep_invalid=keep_invalid)
    except ValueError as exc:
        assert str(exc).strip(), f"empty ValueError message from {reader.__name__}"
        return None
    finally:
        path.unlink(missing_ok=True)
    for warning in warned:
        assert path.name in str(warning.message), f"{reader.__name__} warned without naming the file: {warning.message}"
    assert isinstance(out, list)
    for item in out:
        if isinstance(item, InvalidStrand):
            assert keep_invalid, "InvalidStrand returned without keep_invalid=True"
            assert isinstance(item.message, str) and item.message.strip()
        else:
            assert isinstance(item, Strand), f"reader returned a {type(item).__name__}"
            assert item.points.ndim == 2 and item.points.shape[1] == 3 and item.n_vertices >= 3
            assert np.all(np.isfinite(item.points))
    return out


def check_value_error(exc: ValueError) -> str:
    message = str(exc)
    assert message.strip(), "ValueError without a message"
    return message


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    return tmp_path_factory.mktemp("properties")


@pytest.fixture(scope="module")
def valid_files(workdir):
    """Bytes of a valid file per format, 3 strands of 6, 6 and 5 vertices."""
    strands = sagfree.scenes.groom(2, 6, seed=1) + [sagfree.scenes.horizontal(n=5)]
    files = {}
    for ext, (writer, reader) in FORMATS.items():
        path = workdir / f"valid.{ext}"
        writer(path, strands)
        assert len(reader(path)) == 3
        files[ext] = path.read_bytes()
    return files


# ---------------------------------------------------------------------------------------------------
# 1. random bytes
# ---------------------------------------------------------------------------------------------------

#: Prefixes that get random bytes past each reader's first check (magic numbers, small counts).
MAGIC = [b"HAIR", b"HAIR" + struct.pack("<III", 1, 3, 0b111), b"HAIR" + struct.pack("<III", 2, 6, 0b10),
         b"PK\x03\x04", b"\x93NUMPY", struct.pack("<i", 1), struct.pack("<ii", 1, 3),
         struct.pack("<i", 0), b"v 0 0 0\nv 1 0 0\n", b"l 1 2 3\n"]

random_bytes = st.one_of(
    st.binary(max_size=400),
    st.builds(lambda head, tail: head + tail, st.sampled_from(MAGIC), st.binary(max_size=400)),
)


@pytest.mark.parametrize("ext", list(FORMATS))
@settings(**SETTINGS, max_examples=150)
@given(data=random_bytes, keep_invalid=st.booleans())
@example(data=HUGE_HAIR_HEADER, keep_invalid=False)
def test_reader_random_bytes(workdir, ext, data, keep_invalid):
    check_reader(ext, write_file(workdir, ext, data), keep_invalid)


# ---------------------------------------------------------------------------------------------------
# 2. corrupted valid files
# ---------------------------------------------------------------------------------------------------

corruption = st.tuples(
    st.sampled_from(["truncate", "overwrite", "append", "flip"]),
    st.integers(min_value=0, max_value=1 << 20),       # position, taken modulo the file size + 1
    st.binary(min_size=1, max_size=48),                # payload (overwrite, append) or xor mask (flip)
)


def corrupt(data: bytes, operations) -> bytes:
    for kind, position, payload in operations:
        i = position % (len(data) + 1)
        if kind == "truncate":
            data = data[:i]
        elif kind == "overwrite":
            data = data[:i] + payload + data[i + len(payload):]
        elif kind == "append":
            data = data + payload
        else:  # flip: xor the bytes from i with the payload
            chunk = bytes(a ^ b for a, b in zip(data[i:i + len(payload)], payload))
            data = data[:i] + chunk + data[i + len(chunk):]
    return data


@pytest.mark.parametrize("ext", list(FORMATS))
@settings(**SETTINGS, max_examples=150)
@given(operations=st.lists(corruption, min_size=1, max_size=3), keep_invalid=st.booleans())
@example(operations=[("overwrite", 4, HUGE_HAIR_PATCH)], keep_invalid=True)
@example(operations=[("flip", 254, b"\x00\x80A")], keep_invalid=True)  # a .data point's signaling NaN
def test_reader_corrupted_file(workdir, valid_files, ext, operations, keep_invalid):
    data = corrupt(valid_files[ext], operations)
    out = check_reader(ext, write_file(workdir, ext, data), keep_invalid)
    if data == valid_files[ext]:
        assert out is not None and len(out) == 3


# ---------------------------------------------------------------------------------------------------
# 3. OBJ text fuzz
# ---------------------------------------------------------------------------------------------------

OBJ_TOKENS = ["v", "l", "vt", "vn", "f", "o", "g", "s", "usemtl", "#", "/", "//", "\\", "v#", "l#",
              "0", "1", "2", "3", "4", "7", "10", "-1", "-2", "-3", "-10", "+1", "-0", "00", "1/2", "3/1/2",
              "/1", "1/", "0.0", "-0.0", "0.5", "1e-3", "-3.5", "1e-320", "5e-324", "nan", "NaN", "-nan",
              "inf", "-inf", "Infinity", "1e308", "1.8e308", "1e400", "-1e400", "99999999999999999999",
              "1_0", "0x10", "1.2.3", "e", "garbage", "\u00e9", "\x00", "\t"]
obj_number = st.one_of(st.sampled_from(OBJ_TOKENS[15:54]),
                       st.floats(allow_nan=True, allow_infinity=True).map(repr),
                       st.integers(-5, 12).map(str))
obj_line = st.one_of(
    st.lists(st.sampled_from(OBJ_TOKENS), max_size=8).map(" ".join),
    st.lists(obj_number, min_size=0, max_size=5).map(lambda xs: " ".join(["v", *xs])),
    st.lists(st.integers(-8, 12).map(str), min_size=0, max_size=7).map(lambda xs: " ".join(["l", *xs])),
    st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1)).map(lambda p: "v %r %r %r" % p),
    st.text(max_size=20),
)


@settings(**SETTINGS, max_examples=200)
@given(lines=st.lists(obj_line, max_size=40), newline=st.sampled_from(["\n", "\r\n", "\r"]),
       keep_invalid=st.booleans())
def test_obj_text_fuzz(workdir, lines, newline, keep_invalid):
    data = newline.join(lines).encode("utf-8", errors="surrogatepass")
    check_reader("obj", write_file(workdir, "obj", data), keep_invalid)


# ---------------------------------------------------------------------------------------------------
# 4. random points and material for Strand (and Problem)
# ---------------------------------------------------------------------------------------------------

special_coordinate = st.one_of(
    st.sampled_from([0.0, -0.0, 1e-300, 5e-324, 1e300, 1.7e308, np.nan, np.inf, -np.inf]),
    st.floats(allow_nan=True, allow_infinity=True),                    # nan, inf, huge, tiny, subnormal
)
material_value = st.one_of(
    st.sampled_from([5e-5, 1e-3, 1e9, 4e8, 1300.0, 1.0]),                      # physical
    st.floats(min_value=5e-324, max_value=1.7e308),                            # positive, any scale
    st.sampled_from([0.0, -0.0, -1.0, -1e9, np.nan, np.inf, -np.inf, 5e-324, 1.7e308]),
    st.floats(allow_nan=True, allow_infinity=True),
)
MATERIAL_NAMES = ("radius", "youngs_modulus", "shear_modulus", "density")


@st.composite
def point_arrays(draw, max_vertices=12, bad_shapes=True):
    """(n, 3) points of order 1 times a scale (1e-160 .. 1e160), n in 0..max_vertices, then some of:
    special coordinates (nan, inf, huge, tiny), duplicated vertices, and with ``bad_shapes`` fewer
    than 3 vertices, a wrong number of columns or a ragged list."""
    n = draw(st.sampled_from([*range(3, max_vertices + 1)] * 3 + ([0, 1, 2] if bad_shapes else [])))
    scale = draw(st.sampled_from([1.0, 1.0, 1.0, 0.01, 100.0, 1e-160, 1e-100, 1e100, 1e160]))
    if draw(st.booleans()):   # a tame walk along (1, 0.3, 0.2): edges > 0.2, turns < 90 degrees
        points = [[(i * step + draw(st.floats(-0.4, 0.4))) * scale for step in (1.0, 0.3, 0.2)]
                  for i in range(n)]
    else:                     # uniform in the cube: may repeat vertices or fold back
        points = [[draw(st.floats(-1.0, 1.0)) * scale for _ in range(3)] for _ in range(n)]
    if points:
        for _ in range(draw(st.sampled_from([0, 0, 0, 0, 0, 1, 2, 3]))):   # special coordinates
            row = draw(st.integers(0, n - 1))
            points[row][draw(st.integers(0, 2))] = draw(special_coordinate)
        for _ in range(draw(st.sampled_from([0, 0, 0, 0, 0, 1, 2]))):      # duplicated vertices
            k = draw(st.integers(0, len(points) - 1))
            points.insert(k, list(points[k]))
    shape = draw(st.sampled_from(["array"] * 5 + ["list"] * 3 + (["columns", "ragged"] if bad_shapes else [])))
    if shape == "columns" and points:                                 # wrong number of columns
        width = draw(st.sampled_from([1, 2, 4]))
        return [row[:width] + [0.0] * (width - 3) for row in points]
    if shape == "ragged" and points:
        points[draw(st.integers(0, len(points) - 1))].append(1.0)
        return points
    return np.array(points, dtype=float).reshape(-1, 3) if shape == "array" else points


@st.composite
def materials(draw):
    chosen = draw(st.lists(st.sampled_from(MATERIAL_NAMES), unique=True))
    return {name: draw(material_value) for name in chosen}


@settings(**SETTINGS, max_examples=300)
@given(points=point_arrays(), material=materials(),
       root=st.sampled_from(["clamped", "pinned", "clamped", "pinned", "free", ""]))
def test_strand_random_input(points, material, root):
    try:
        strand = Strand(points, root=root, **material)
    except ValueError as exc:
        check_value_error(exc)
        return
    assert strand.points.shape == (strand.n_vertices, 3) and strand.n_vertices >= 3
    assert np.all(np.isfinite(strand.points)) and np.all(strand.edge_lengths > 0)
    for name in MATERIAL_NAMES:
        value = getattr(strand, name)
        assert np.isfinite(value) and value > 0
    assert strand.theta.shape == (strand.n_vertices - 1,)


def build_problem_or_value_error(strand):
    """Problem(strand) and its residual at p0, or None when Problem raises ValueError."""
    try:
        problem = sagfree.Problem(strand)
    except ValueError as exc:
        check_value_error(exc)
        return None, None
    return problem, problem.residual(problem.p0)


@settings(**SETTINGS, max_examples=30)
@given(points=point_arrays(max_vertices=10, bad_shapes=False), material=materials())
@example(points=[[0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [0.02, 0.01, 0.0]], material={"radius": 1e200})
@example(points=[[0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [0.02, 0.01, 0.0]], material={"density": 5e-324})
def test_problem_from_random_strand_has_a_finite_residual_or_refuses(points, material):
    """Strand builds or raises ValueError; a built Strand gives a Problem whose residual at p0 is
    finite, or a ValueError (radius 1e200 once raised OverflowError, density 5e-324 gave NaN)."""
    try:
        strand = Strand(points, **material)
    except ValueError as exc:
        check_value_error(exc)
        return
    problem, residual = build_problem_or_value_error(strand)
    if problem is not None:
        assert np.all(np.isfinite(residual)), f"non-finite residual {residual} for {strand!r}"


@st.composite
def realistic_strands(draw):
    """Random walks of 3..10 vertices with 0.1-10 mm edges and material in physical ranges."""
    n = draw(st.integers(3, 10))
    steps = []
    for _ in range(n - 1):
        direction = np.array([draw(st.floats(-1, 1)) for _ in range(3)])
        norm = np.linalg.norm(direction)
        direction = direction / norm if norm > 0.1 else np.array([1.0, 0.0, 0.0])
        steps.append(direction * draw(st.floats(1e-4, 1e-2)))
    points = np.vstack([np.zeros(3), np.cumsum(steps, axis=0)]) + np.array(
        [draw(st.floats(-0.1, 0.1)) for _ in range(3)])
    log_uniform = lambda lo, hi: st.floats(np.log10(lo), np.log10(hi)).map(lambda e: 10.0**e)  # noqa: E731
    material = dict(radius=draw(log_uniform(1e-6, 1e-3)), youngs_modulus=draw(log_uniform(1e6, 1e12)),
                    shear_modulus=draw(log_uniform(1e6, 1e12)), density=draw(log_uniform(1e2, 1e4)))
    return points, material, draw(st.sampled_from(["clamped", "pinned"]))


@settings(**SETTINGS, max_examples=25)
@given(case=realistic_strands())
def test_problem_on_realistic_random_strand(case):
    points, material, root = case
    try:
        strand = Strand(points, root=root, **material)
    except ValueError as exc:          # a random walk may fold back by more than 170 degrees
        check_value_error(exc)
        return
    problem = sagfree.Problem(strand)
    residual = problem.residual(problem.p0)
    assert residual.ndim == 1 and np.all(np.isfinite(residual))
    jacobian = problem.jacobian(problem.p0)
    assert jacobian.shape == (residual.size, problem.n_parameters)
    assert np.all(np.isfinite(jacobian.data))


# ---------------------------------------------------------------------------------------------------
# 5. random bounds and options for Problem
# ---------------------------------------------------------------------------------------------------

BOUND_BLOCKS = ("rest_length", "rest_curvature", "rest_twist", "bend_stiffness", "stretch_stiffness",
                "nonsense_block")
CURVATURES = ("4d", "2d-average", "2d-slerp", "5d")
STIFFNESS = ("element", "strand", "fixed", "weird")
VALID_CURVATURES, VALID_STIFFNESS = CURVATURES[:3], STIFFNESS[:3]

bound_value = st.one_of(
    st.sampled_from([-1e3, -100.0, -1.0, -0.05, -0.01, 0.0, 0.01, 0.05, 0.5, 1.0, 2.0, 100.0, 1e3]),
    st.floats(allow_nan=True, allow_infinity=True),
)
bound_pair = st.one_of(
    st.tuples(st.sampled_from([-1e3, -100.0, -10.0, -3.0]), st.sampled_from([3.0, 10.0, 100.0, 1e3])),  # holds p0
    st.tuples(bound_value, bound_value),                        # anything: nan, inf, lo > hi, p0 outside
)

_reference_problems = {}


def fixed_strand():
    return sagfree.scenes.groom(1, 8, seed=2)[0]


def reference_blocks(curvature, stiffness):
    """{block: p0 entries} of the default Problem with these (valid) options."""
    key = (curvature, stiffness)
    if key not in _reference_problems:
        problem = sagfree.Problem(fixed_strand(), curvature=curvature, stiffness=stiffness)
        _reference_problems[key] = {b: problem.p0[ix] for b, ix in problem.blocks.items()}
    return _reference_problems[key]


@settings(**SETTINGS, max_examples=60)
@given(bounds=st.dictionaries(st.sampled_from(BOUND_BLOCKS), bound_pair, max_size=3),
       curvature=st.sampled_from(CURVATURES + VALID_CURVATURES * 2),
       stiffness=st.sampled_from(STIFFNESS + VALID_STIFFNESS * 2),
       as_none=st.booleans())
def test_problem_random_bounds_and_options(bounds, curvature, stiffness, as_none):
    offending = set()
    if curvature not in VALID_CURVATURES:
        offending.add(curvature)
    if stiffness not in VALID_STIFFNESS:
        offending.add(stiffness)
    if not offending:
        blocks = reference_blocks(curvature, stiffness)
        for name, (lo, hi) in bounds.items():
            if name not in blocks:
                offending.add(name)
                continue
            p0 = blocks[name]
            if not (np.isfinite(lo) and np.isfinite(hi)) or lo > hi or np.any(p0 < lo) or np.any(p0 > hi):
                offending.add(name)
    strand = fixed_strand()
    try:
        problem = sagfree.Problem(strand, curvature=curvature, stiffness=stiffness,
                                  bounds=None if (as_none and not bounds) else dict(bounds))
    except ValueError as exc:
        message = check_value_error(exc)
        assert offending, f"unexpected ValueError {message!r}"
        assert any(name in message for name in offending), \
            f"the message {message!r} names none of the offending {sorted(offending)}"
        return
    assert not offending, f"Problem accepted the offending {sorted(offending)}"
    for name, (lo, hi) in bounds.items():
        ix = problem.blocks[name]
        assert np.all(problem.lower[ix] == lo) and np.all(problem.upper[ix] == hi)
    residual = problem.residual(problem.p0)
    assert np.all(np.isfinite(residual))
    assert problem.jacobian(problem.p0).shape == (residual.size, problem.n_parameters)
