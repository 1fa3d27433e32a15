"""OpenUSD BasisCurves stages (scenes.usd): strands in metres and Z up from any stage, parameters
written back as ``sagfree:`` primvars, read back by ``sagfree simulate`` without --params."""
import json
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("pxr")
from pxr import Sdf, Usd, UsdGeom  # noqa: E402

import sagfree  # noqa: E402
from sagfree.cli import main  # noqa: E402
from sagfree.formulation.strand import InvalidStrand  # noqa: E402
from sagfree.scenes.usd import load_stage, load_stage_parameters, save_stage  # noqa: E402

N = 14                                      # vertices per curve
LOCAL = np.c_[np.linspace(0.0, 10.0, N), np.zeros(N), np.zeros(N)]   # 10 stage units (cm) along x
B_WIDTHS = np.linspace(0.006, 0.010, N)     # per-vertex diameters of /Groom/Turned/B (cm), mean 0.008


def groom_stage(path, up="Z", transform=True):
    """A cm stage: /Groom/A holds two straight curves (constant widths 0.01 cm, uniform density),
    /Groom/Turned/B one curve under an Xform (translate (1, 2, 3), rotate 90 degrees about z, scale 2;
    per-vertex widths, a constant Young's modulus); /Head is another prim the output must keep."""
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageMetersPerUnit(stage, 0.01)
    UsdGeom.SetStageUpAxis(stage, up)
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/Groom").GetPrim())
    a = UsdGeom.BasisCurves.Define(stage, "/Groom/A")
    a.CreateTypeAttr("linear")
    a.CreateCurveVertexCountsAttr([N, N])
    a.CreatePointsAttr(np.r_[LOCAL, LOCAL + [0.0, 1.0, 0.0]].tolist())
    a.CreateWidthsAttr([0.01])
    a.SetWidthsInterpolation("constant")
    UsdGeom.PrimvarsAPI(a).CreatePrimvar("sagfree:density", Sdf.ValueTypeNames.DoubleArray, "uniform").Set(
        [1100.0, 1200.0])
    turned = UsdGeom.Xform.Define(stage, "/Groom/Turned")
    if transform:
        api = UsdGeom.XformCommonAPI(turned)
        api.SetTranslate((1.0, 2.0, 3.0))
        api.SetRotate((0.0, 0.0, 90.0))
        api.SetScale((2.0, 2.0, 2.0))
    b = UsdGeom.BasisCurves.Define(stage, "/Groom/Turned/B")
    b.CreateTypeAttr("linear")
    b.CreateCurveVertexCountsAttr([N])
    b.CreatePointsAttr(LOCAL.tolist())
    b.CreateWidthsAttr(B_WIDTHS.tolist())   # vertex interpolation: USD's default for widths
    UsdGeom.PrimvarsAPI(b).CreatePrimvar("sagfree:youngsModulus", Sdf.ValueTypeNames.Double, "constant").Set(2e9)
    head = UsdGeom.Sphere.Define(stage, "/Head")
    head.CreateRadiusAttr(9.5)
    head.GetPrim().SetCustomDataByKey("note", "kept")
    stage.Save()
    return path


def curves_stage(path, kind="linear", basis=None, wrap=None, points=None, counts=None):
    """One BasisCurves prim /Hair in a metre, Z-up stage."""
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    UsdGeom.SetStageUpAxis(stage, "Z")
    curves = UsdGeom.BasisCurves.Define(stage, "/Hair")
    curves.CreateTypeAttr(kind)
    if basis:
        curves.CreateBasisAttr(basis)
    if wrap:
        curves.CreateWrapAttr(wrap)
    points = np.array(LOCAL * 0.01 if points is None else points)
    curves.CreateCurveVertexCountsAttr(counts or [len(points)])
    curves.CreatePointsAttr(points.tolist())
    stage.Save()
    return path


# --- reading --------------------------------------------------------------------------------------

def test_z_up_stage_in_cm_with_a_transform(tmp_path):
    strands = load_stage(groom_stage(tmp_path / "groom.usda"))
    assert len(strands) == 3  # /Groom/A's two curves, then /Groom/Turned/B: traversal order
    expected = LOCAL * 0.01
    np.testing.assert_allclose(strands[0].points, expected, atol=1e-9)
    np.testing.assert_allclose(strands[1].points, expected + [0.0, 0.01, 0.0], atol=1e-9)
    # B: scaled by 2, x turned into y, moved by (1, 2, 3) cm: its tip (10, 0, 0) is at (1, 22, 3) cm
    np.testing.assert_allclose(strands[2].points[0], [0.01, 0.02, 0.03], atol=1e-9)
    np.testing.assert_allclose(strands[2].points[-1], [0.01, 0.22, 0.03], atol=1e-9)
    assert strands[2].length == pytest.approx(0.2, rel=1e-7)
    # widths are diameters: constant 0.01 cm -> 50 um; B's mean 0.008 cm, scaled by 2 -> 80 um
    assert [s.radius for s in strands] == pytest.approx([5e-5, 5e-5, 8e-5], rel=1e-6)
    assert [s.density for s in strands] == [1100.0, 1200.0, 1300.0]        # uniform primvar, then MATERIAL
    assert [s.youngs_modulus for s in strands] == [1e9, 1e9, 2e9]          # constant primvar on B only
    assert {s.shear_modulus for s in strands} == {4e8} and {s.root for s in strands} == {"clamped"}


def test_y_up_stage_is_turned_into_z_up(tmp_path):
    strands = load_stage(groom_stage(tmp_path / "groom.usda", up="Y"))
    # (x, y, z) Y-up -> (x, -z, y) Z-up: A's second curve, 1 cm along +y (up), is 1 cm higher
    np.testing.assert_allclose(strands[0].points, LOCAL * 0.01, atol=1e-9)
    np.testing.assert_allclose(strands[1].points, LOCAL * 0.01 + [0.0, 0.0, 0.01], atol=1e-9)
    # B's tip at (1, 22, 3) cm in the Y-up world stands 22 cm high
    np.testing.assert_allclose(strands[2].points[0], [0.01, -0.03, 0.02], atol=1e-9)
    np.testing.assert_allclose(strands[2].points[-1], [0.01, -0.03, 0.22], atol=1e-9)


def test_units_and_material_keywords(tmp_path):
    path = groom_stage(tmp_path / "groom.usda", transform=False)
    assert len(sagfree.load(path, units="cm")) == 3  # the stage's own unit: accepted
    with pytest.raises(ValueError, match=r"groom.usda: the stage is in metersPerUnit 0.01; units='m'"):
        sagfree.load(path, units="m")
    strands = sagfree.load(path, radius=3e-5, youngs_modulus=5e9)
    assert {s.radius for s in strands} == {3e-5} and {s.youngs_modulus for s in strands} == {5e9}
    assert [s.density for s in strands] == [1100.0, 1200.0, 1300.0]


def test_catmull_rom_control_vertices_other_cubics_and_loops_refused(tmp_path):
    path = curves_stage(tmp_path / "cr.usda", "cubic", "catmullRom")
    stage = Usd.Stage.Open(str(path))
    curves = UsdGeom.BasisCurves(stage.GetPrimAtPath("/Hair"))
    curves.CreateWidthsAttr(np.linspace(6e-5, 1e-4, N - 2).tolist())  # varying: one per segment end
    curves.SetWidthsInterpolation("varying")
    stage.Save()
    strands = load_stage(path)
    np.testing.assert_allclose(strands[0].points, LOCAL * 0.01, atol=1e-9)  # the control vertices
    assert strands[0].radius == pytest.approx(4e-5, rel=1e-6)
    with pytest.raises(ValueError, match=r"bs.usda: /Hair: cubic bspline curves are not read.*linear"):
        load_stage(curves_stage(tmp_path / "bs.usda", "cubic", "bspline"))
    with pytest.raises(ValueError, match=r"loop.usda: /Hair: periodic curves .* closed loops"):
        load_stage(curves_stage(tmp_path / "loop.usda", wrap="periodic"))


def test_bad_stages_name_the_file_prim_curve_and_vertex(tmp_path):
    empty = Usd.Stage.CreateNew(str(tmp_path / "empty.usda"))
    UsdGeom.Xform.Define(empty, "/World")
    empty.Save()
    with pytest.raises(ValueError, match=r"empty.usda: the stage has no BasisCurves prim"):
        sagfree.load(tmp_path / "empty.usda")
    bad = np.r_[LOCAL, LOCAL] * 0.01
    bad[N + 5] = np.nan
    path = curves_stage(tmp_path / "nan.usda", points=bad, counts=[N, N])
    with pytest.raises(ValueError, match=r"nan.usda: /Hair: curve 1: vertex 5 has a non-finite coordinate"):
        load_stage(path)
    kept = load_stage(path, keep_invalid=True)
    assert isinstance(kept[1], InvalidStrand) and "/Hair: curve 1: vertex 5" in kept[1].message
    assert not isinstance(kept[0], InvalidStrand)
    with pytest.raises(ValueError, match=r"counts.usda: /Hair: curveVertexCounts add up to 20"):
        load_stage(curves_stage(tmp_path / "counts.usda", counts=[10, 10]))
    (tmp_path / "junk.usda").write_text("#usda 1.0\n( not a stage")
    with pytest.raises(ValueError, match=r"junk.usda: not a readable USD stage"):
        load_stage(tmp_path / "junk.usda")
    with pytest.raises(FileNotFoundError, match="missing.usda: no such file"):
        load_stage(tmp_path / "missing.usda")


def test_without_usd_core_the_error_says_what_to_install(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "pxr", None)  # import pxr fails as without the package
    with pytest.raises(ImportError, match=r'pip install "sagfree\[usd\]"'):
        load_stage(tmp_path / "groom.usda")
    assert main(["optimize", "horizontal", "-o", str(tmp_path / "out.usda"), "--quiet"]) == 2
    assert 'pip install "sagfree[usd]"' in capsys.readouterr().err


# --- writing --------------------------------------------------------------------------------------

PER_EDGE = {"sagfree:restLength": "rest_length", "sagfree:stretchModulus": "stretch_modulus"}
PER_VERTEX = {"sagfree:restCurvature": "rest_curvature", "sagfree:restTwist": "rest_twist",
              "sagfree:bendModulus": "bend_modulus", "sagfree:twistModulus": "twist_modulus"}
MULTIPLIERS = {"sagfree:stretchMultiplier": ("stretch_modulus", "youngs_modulus", "edge"),
               "sagfree:bendMultiplier": ("bend_modulus", "youngs_modulus", "vertex"),
               "sagfree:twistMultiplier": ("twist_modulus", "shear_modulus", "vertex")}


def primvar(prim, name, interpolation):
    """The values of a primvar, checked to exist with ``interpolation``."""
    pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar(name)
    assert pv and pv.HasValue(), f"{prim.GetPath()} lacks {name}"
    assert pv.GetInterpolation() == interpolation, name
    return pv.Get()


def test_round_trip_primvars_equal_the_results_and_the_stage_is_kept(tmp_path):
    source = groom_stage(tmp_path / "groom.usda")
    strands = load_stage(source)
    results = sagfree.optimize(strands, jobs=1)
    assert [r.status for r in results] == ["converged"] * 3
    out = tmp_path / "out" / "groom.sagfree.usda"
    save_stage(out, strands, results, "asc", {"stiffness": "element"}, source=source)
    assert not list(out.parent.glob(".*"))  # no temporary file left behind

    stage = Usd.Stage.Open(str(out))
    assert UsdGeom.GetStageMetersPerUnit(stage) == 0.01 and UsdGeom.GetStageUpAxis(stage) == "Z"
    head = UsdGeom.Sphere(stage.GetPrimAtPath("/Head"))
    assert head.GetRadiusAttr().Get() == 9.5 and head.GetPrim().GetCustomDataByKey("note") == "kept"
    assert stage.GetPrimAtPath("/Groom/Turned").GetAttribute("xformOp:translate").Get() == (1, 2, 3)
    prims = [(stage.GetPrimAtPath("/Groom/A"), strands[:2], results[:2]),
             (stage.GetPrimAtPath("/Groom/Turned/B"), strands[2:], results[2:])]
    for prim, mine, done in prims:
        n = sum(s.n_vertices for s in mine)
        starts = np.r_[0, np.cumsum([s.n_vertices for s in mine])]
        for name, block in {**PER_EDGE, **PER_VERTEX}.items():
            values = np.asarray(primvar(prim, name, "vertex"))
            assert len(values) == n, name
            for s, r, start in zip(mine, done, starts):
                own = values[start: start + s.n_vertices]
                if name in PER_EDGE:  # edge j at vertex j, 0 at the tip
                    np.testing.assert_array_equal(own[:-1], r.physical[block])
                    assert np.all(own[-1] == 0)
                else:                 # interior vertex i at vertex i, 0 at both ends
                    np.testing.assert_array_equal(own[1:-1], r.physical[block])
                    assert np.all(own[0] == 0) and np.all(own[-1] == 0)
        for name, (block, modulus, kind) in MULTIPLIERS.items():
            values = np.asarray(primvar(prim, name, "vertex"))
            for s, r, start in zip(mine, done, starts):
                inner = slice(start, start + s.n_vertices - 1) if kind == "edge" else \
                    slice(start + 1, start + s.n_vertices - 1)
                np.testing.assert_allclose(values[inner], r.physical[block] / getattr(s, modulus), rtol=1e-15)
        assert list(primvar(prim, "sagfree:status", "uniform")) == [r.status for r in done]
        assert list(primvar(prim, "sagfree:message", "uniform")) == [r.message for r in done]
        assert list(primvar(prim, "sagfree:minEigenvalue", "uniform")) == [r.min_eigenvalue for r in done]
        assert list(primvar(prim, "sagfree:length", "uniform")) == [s.length for s in mine]
        counts = list(primvar(prim, "sagfree:parameterCount", "uniform"))
        assert counts == [r.p.size for r in done]
        np.testing.assert_array_equal(primvar(prim, "sagfree:parameters", "constant"),
                                      np.concatenate([r.p for r in done]))
        assert primvar(prim, "sagfree:solver", "constant") == "asc"
        assert json.loads(primvar(prim, "sagfree:problemOptions", "constant")) == {"stiffness": "element"}
        # the material the parameters were computed for, on the curves
        assert list(primvar(prim, "sagfree:density", "uniform")) == [s.density for s in mine]
    b = stage.GetPrimAtPath("/Groom/Turned/B")
    assert primvar(b, "sagfree:youngsModulus", "constant") == 2e9  # the source's own, as it was

    # the stage reads back as the same strands, and its parameters as the Results
    back = load_stage(out)
    for a, b in zip(strands, back):
        np.testing.assert_array_equal(a.points, b.points)
        assert (a.radius, a.youngs_modulus, a.shear_modulus, a.density) == \
               (b.radius, b.youngs_modulus, b.shear_modulus, b.density)
    params = load_stage_parameters(out)
    params.check_matches(back, str(out))
    assert params.solver == "asc" and params.status == ["converged"] * 3
    for k, r in enumerate(results):
        np.testing.assert_array_equal(params.p[k], r.p)
        for name, values in r.physical.items():
            np.testing.assert_array_equal(params.physical[name][k], values)
    summary = json.loads((out.parent / "groom.sagfree.json").read_text())
    assert [s["status"] for s in summary["strands"]] == params.status
    assert load_stage_parameters(source) is None  # the source is untouched


def test_a_new_stage_for_strands_from_elsewhere(tmp_path):
    flipped = sagfree.scenes.flipped(n=9)  # material angles pi on alternate edges
    strands = [sagfree.scenes.horizontal(n=12), flipped,
               sagfree.Strand(sagfree.scenes.curly(n=15).points, radius=4e-5, youngs_modulus=2e9, density=1100.0)]
    results = sagfree.optimize(strands, jobs=1, stiffness="strand")
    failed = sagfree.contract.result.failed_result("asc", "poisoned on purpose")
    results[1] = failed
    path = sagfree.save(tmp_path / "new.usdc", strands, results, problem_options={"stiffness": "strand"})
    assert path == tmp_path / "new.usdc" and (tmp_path / "new.json").exists()
    stage = Usd.Stage.Open(str(path))
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0 and UsdGeom.GetStageUpAxis(stage) == "Z"
    prim = stage.GetPrimAtPath("/Strands")
    curves = UsdGeom.BasisCurves(prim)
    assert curves.GetTypeAttr().Get() == "linear" and list(curves.GetCurveVertexCountsAttr().Get()) == [12, 9, 15]
    assert curves.GetWidthsInterpolation() == "uniform"
    np.testing.assert_allclose(curves.GetWidthsAttr().Get(), [1e-4, 1e-4, 8e-5], rtol=1e-7)
    rest = np.asarray(primvar(prim, "sagfree:restLength", "vertex"))
    assert np.isnan(rest[12: 21]).all() and not np.isnan(rest[:12]).any()  # the failed strand: NaN
    back = sagfree.load(path)
    for a, b in zip(strands, back):
        np.testing.assert_allclose(b.points, a.points, rtol=0, atol=1e-7 * np.abs(a.points).max())  # float32
        np.testing.assert_array_equal(a.theta, b.theta)
        assert (a.youngs_modulus, a.density) == (b.youngs_modulus, b.density)
        assert b.radius == pytest.approx(a.radius, rel=1e-7)
    params = load_stage_parameters(path)
    params.check_matches(back, str(path))
    assert params.problem_options == {"stiffness": "strand"} and params.p[1].size == 0
    assert params.message[1] == "poisoned on purpose"
    assert np.isnan(params.physical["bend_modulus"][1]).all()


def test_material_keywords_reach_the_copied_stage(tmp_path):
    """A copied stage is made to say what the strands are: widths and material primvars follow the
    keywords given to load (the command line's --radius), in the source attribute's own form."""
    source = groom_stage(tmp_path / "groom.usda")
    strands = load_stage(source, radius=3e-5, youngs_modulus=5e9)
    save_stage(tmp_path / "copy.usda", strands, source=source)
    back = load_stage(tmp_path / "copy.usda")
    assert [b.radius for b in back] == pytest.approx([3e-5] * 3, rel=1e-7)
    assert [b.youngs_modulus for b in back] == [5e9] * 3 and [b.density for b in back] == [1100.0, 1200.0, 1300.0]
    stage = Usd.Stage.Open(str(tmp_path / "copy.usda"))
    assert primvar(stage.GetPrimAtPath("/Groom/Turned/B"), "sagfree:youngsModulus", "constant") == 5e9
    with pytest.raises(ValueError, match=r"copy2.usda: 2 strands, but the curves of .*groom.usda are 3"):
        save_stage(tmp_path / "copy2.usda", strands[:2], source=source)
    assert not (tmp_path / "copy2.usda").exists()


# --- the command line -----------------------------------------------------------------------------

def test_optimize_a_groom_stage_then_simulate_the_stage_it_wrote(tmp_path):
    """sagfree optimize groom.usda -o out.usda (cm, a transform, two curve prims); out.usda carries the
    primvars; sagfree simulate out.usda needs no --params and the strands hold."""
    groom_stage(tmp_path / "groom.usda")
    cli = [sys.executable, "-m", "sagfree.cli"]
    run = subprocess.run([*cli, "optimize", "groom.usda", "-o", "out.usda", "--jobs", "1", "--quiet"],
                         capture_output=True, text=True, cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    assert "converged 3" in run.stdout and "wrote out.usda and out.json" in run.stdout
    stage = Usd.Stage.Open(str(tmp_path / "out.usda"))
    for path, count in (("/Groom/A", 2), ("/Groom/Turned/B", 1)):
        prim = stage.GetPrimAtPath(path)
        assert list(primvar(prim, "sagfree:status", "uniform")) == ["converged"] * count
        assert len(primvar(prim, "sagfree:bendMultiplier", "vertex")) == count * N
        assert max(primvar(prim, "sagfree:bendMultiplier", "vertex")) > 1.5  # the roots stiffened
    run = subprocess.run([*cli, "simulate", "out.usda", "--jobs", "1", "--quiet", "--steps", "20"],
                         capture_output=True, text=True, cwd=tmp_path)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "3/3 strands stay within 1e-06" in run.stdout and "3/3 hold after a push" in run.stdout
    assert "moves" not in run.stdout


def test_simulate_a_stage_without_parameters_needs_params(tmp_path, capsys):
    groom_stage(tmp_path / "groom.usda")
    assert main(["simulate", str(tmp_path / "groom.usda"), "--quiet"]) == 2
    assert "groom.usda: the stage's curves carry no sagfree parameters" in capsys.readouterr().err
    assert main(["simulate", "horizontal", "--quiet"]) == 2
    assert "--params FILE is needed" in capsys.readouterr().err


def test_resume_with_a_stage_output(tmp_path, monkeypatch, capsys):
    """An interrupted run writing a .usda output resumes from OUT.partial/ as a .npz run does."""
    import sagfree.frontend.batch as batch

    curves_stage(tmp_path / "two.usda", points=np.r_[LOCAL, LOCAL + [0, 1, 0]] * 0.01, counts=[N, N])
    out = tmp_path / "two.sagfree.usda"
    command = ["optimize", str(tmp_path / "two.usda"), "-o", str(out), "--jobs", "1", "--quiet"]
    real = batch.optimize

    def interrupted(strands, **options):  # solves the first strand, then Ctrl-C
        real(strands[:1], **options)
        raise KeyboardInterrupt

    monkeypatch.setattr(batch, "optimize", interrupted)
    assert main(command) == 130 and not out.exists()
    monkeypatch.setattr(batch, "optimize", real)
    assert main([*command, "--resume"]) == 0
    assert "resuming: 1 of 2 strands" in capsys.readouterr().out
    assert load_stage_parameters(out).status == ["converged", "converged"]
    assert not (tmp_path / "two.sagfree.usda.partial").exists()


def test_a_rendering_width_gets_a_warning(tmp_path):
    path = curves_stage(tmp_path / "thick.usda")
    stage = Usd.Stage.Open(str(path))
    curves = UsdGeom.BasisCurves(stage.GetPrimAtPath("/Hair"))
    curves.CreateWidthsAttr([0.004])  # 2 mm on a 10 cm strand
    curves.SetWidthsInterpolation("constant")
    stage.Save()
    with pytest.warns(UserWarning, match=r"thick.usda: the widths gives 1 strand\(s\) an implausible radius"):
        strands = load_stage(path)
    assert strands[0].radius == pytest.approx(0.002)
