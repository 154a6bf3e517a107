"""VTK/PVD export round-trips through meshio."""

import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import meshio
import numpy as np
import pytest

from willmore_nlp import load_run
from willmore_nlp.export import vertex_normals
from willmore_nlp.geometry import mean_curvature_vector
from willmore_nlp.mesh import shapes
from willmore_nlp.mesh.io import load_mesh


@pytest.mark.parametrize(("problem", "sets"), [("circle", ["n=16"]), ("sphere", ["subdivisions=1"])])
def test_export_round_trip(tmp_path, problem: str, sets: list[str]) -> None:
    run_dir = tmp_path / "run"
    args = [sys.executable, "-m", "willmore_nlp.cli", "run", problem, "--out", str(run_dir), "--steps", "2",
            "--quiet"]
    for s in sets:
        args += ["--set", s]
    subprocess.run(args, check=True, capture_output=True)
    r = subprocess.run([sys.executable, "-m", "willmore_nlp.cli", "export", str(run_dir), "--out",
                        str(tmp_path / "vtk")], check=True, capture_output=True, text=True)
    assert "run.pvd" in r.stdout
    run = load_run(run_dir)
    pvd = ET.parse(tmp_path / "vtk" / "run.pvd").getroot()
    sets_ = pvd.findall("./Collection/DataSet")
    assert [float(x.get("timestep")) for x in sets_] == pytest.approx(run.times)
    for k, (ds, mesh, Y) in enumerate(zip(sets_, run.states, run.Y, strict=True)):
        m = meshio.read(tmp_path / "vtk" / ds.get("file"))
        m_dim = mesh.m
        np.testing.assert_array_equal(m.points[:, :m_dim], mesh.vertices)
        np.testing.assert_array_equal(m.cells[0].data, mesh.simplices)
        np.testing.assert_array_equal(m.point_data["Y"][:, :m_dim], Y)
        np.testing.assert_array_equal(m.point_data["mean_curvature_vector"][:, :m_dim],
                                      mean_curvature_vector(mesh))
        if k > 0:
            v = (mesh.vertices - run.states[k - 1].vertices) / (run.times[k] - run.times[k - 1])
            np.testing.assert_allclose(m.point_data["velocity"][:, :m_dim], v, rtol=1e-12, atol=0)
            np.testing.assert_allclose(m.point_data["normal_speed"], np.einsum("ij,ij->i", v, vertex_normals(mesh)),
                                       rtol=1e-12, atol=1e-15)


def test_vertex_normals_outward() -> None:
    c = shapes.regular_polygon(12, 2.0)
    np.testing.assert_allclose(vertex_normals(c), c.vertices / 2.0, atol=1e-12)
    s = shapes.icosphere(3)
    n = vertex_normals(s)
    assert np.all(np.einsum("ij,ij->i", n, s.vertices) > 0.999)


def test_a_space_curve_exports_its_principal_normal_and_normal_speed() -> None:
    """A space curve's ``normal`` and ``normal_speed`` were zero at every vertex (a moving trefoil looked motionless
    in ParaView; a new user's check). A regular 24-gon of radius 2 in a tilted plane of R^3, growing by a factor
    1 + e in dt: the normal is the principal normal, toward the centre, and the normal speed -2 e / dt (the
    velocity points away from the centre). A plane curve keeps its outward normal."""
    from willmore_nlp.export import state_mesh

    c = shapes.regular_polygon(24, 2.0)
    Q = np.linalg.qr(np.random.default_rng(2).standard_normal((3, 3)))[0]
    X = np.column_stack([c.vertices, np.zeros(24)]) @ Q.T + [0.5, -1.0, 2.0]
    curve = shapes.closed_curve(X)
    e, dt = 1e-3, 0.01
    prev = [0.5, -1.0, 2.0] + (X - [0.5, -1.0, 2.0]) / (1 + e)
    data = state_mesh(curve, X, prev, dt).point_data
    np.testing.assert_allclose(data["normal"], -(X - [0.5, -1.0, 2.0]) / 2.0, atol=1e-12)
    np.testing.assert_allclose(data["normal_speed"], -2.0 * e / (1 + e) / dt, rtol=1e-10)
    np.testing.assert_allclose(state_mesh(c, c.vertices, None, dt).point_data["normal"][:, :2], c.vertices / 2.0,
                               atol=1e-12)


def test_one_state_exports_to_a_mesh_file(tmp_path, capsys) -> None:
    """``export RUN --out NAME.obj`` (.off, .ply, .stl, .npz, a curve's .txt) writes one state, the last unless
    ``--step`` names another (found by a new-user check: ``--out x.obj`` made a folder named x.obj holding VTU files).
    OBJ, PLY, npz and the text curve read back bit for bit; a step the run does not have, or --step with a folder, is
    one line and exit 2 (the command line in-process; its subprocess exit codes: test_validation_inputs.py)."""
    from willmore_nlp import cli

    for problem, sets, files in (("sphere", ["subdivisions=1"], ("s.obj", "s.npz", "s.ply")),
                                 ("circle", ["n=16"], ("c.txt",))):
        run_dir = tmp_path / problem
        assert cli.main(["run", problem, "--out", str(run_dir), "--steps", "2", "--quiet",
                         *[a for s in sets for a in ("--set", s)]]) == 0
        run = load_run(run_dir)
        for name in files:
            for step, k in ((None, -1), (0, 0), (1, 1)):
                out = tmp_path / f"{step}_{name}"
                capsys.readouterr()
                assert cli.main(["export", str(run_dir), "--out", str(out),
                                 *(["--step", str(step)] if step is not None else [])]) == 0
                # (the step written, also by default: it said "(step last)")
                assert capsys.readouterr().out.strip() == f"wrote {out} (step {2 if step is None else step})"
                mesh = load_mesh(out)  # (PLY: it was single precision, 'property float', 3e-8 off)
                assert mesh.vertices.tobytes() == run.states[k].vertices.tobytes()
    capsys.readouterr()
    assert cli.main(["export", str(tmp_path / "sphere"), "--out", str(tmp_path / "x.obj"), "--step", "7"]) == 2
    assert "no state of step 7 (the run has steps 0 to 2)" in capsys.readouterr().err
    assert cli.main(["export", str(tmp_path / "sphere"), "--out", str(tmp_path / "vtk"), "--step", "1"]) == 2
    assert "--step 1: one state is exported to a mesh file" in capsys.readouterr().err
    assert not (tmp_path / "vtk").exists() and not (tmp_path / "x.obj").exists()


def test_export_to_a_suffix_that_is_no_mesh_format_is_refused(tmp_path, capsys) -> None:
    """Found by a new-user check (2026-12-01): ``export RUN --out x.csv`` made a folder x.csv of VTU files. A suffix
    that is not a mesh format is one line and exit 2 naming the formats, nothing written; a folder name without a
    suffix (or with a number after its dot, or an existing folder) still gets the VTU files."""
    from willmore_nlp import cli

    run_dir = tmp_path / "run"
    assert cli.main(["run", "circle", "--set", "n=12", "--out", str(run_dir), "--steps", "1", "--quiet"]) == 0
    capsys.readouterr()
    for name in ("x.csv", "x.VTU", "states.pvd"):
        assert cli.main(["export", str(run_dir), "--out", str(tmp_path / name)]) == 2
        err = capsys.readouterr().err.strip()
        assert err == (f"willmore-nlp: error: --out {tmp_path / name}: {Path(name).suffix.lower()} is not a mesh "
                       "format: give a mesh file (.obj, .ply, .off, .stl, .txt, .curve, .xy, .xyz, .npz) for one "
                       "state, or a folder name without a suffix for the VTU files and run.pvd")
        assert not (tmp_path / name).exists()
    (tmp_path / "made.d").mkdir()
    for name in ("vtk", "vtk_h0.5", "made.d"):
        assert cli.main(["export", str(run_dir), "--out", str(tmp_path / name)]) == 0
        assert (tmp_path / name / "run.pvd").is_file()


def test_export_replaces_nothing_unless_asked_and_never_a_runs_record(tmp_path, capsys) -> None:
    """Found by a new-user check (2026-12-01): ``export RUN --out FILE`` replaced any existing file (a user's
    precious.obj, another run's states/state_000001.npz), and the folder export wrote into any folder (replacing
    another export's run.pvd and leaving its later state_*.vtu beside the new ones). An existing file, or a folder that
    is not empty, is now one line and exit 2 naming it and --overwrite; --overwrite replaces a file, and in a folder
    only an earlier export (its run.pvd and the state_*.vtu its run.pvd lists, other files staying); a run's own
    files, its states/ folder and the run directory itself are refused even with --overwrite."""
    from willmore_nlp import cli

    long_run, short = tmp_path / "long", tmp_path / "short"
    assert cli.main(["run", "circle", "--set", "n=12", "--out", str(long_run), "--steps", "4", "--quiet"]) == 0
    assert cli.main(["run", "circle", "--set", "n=12", "--out", str(short), "--steps", "1", "--quiet"]) == 0
    capsys.readouterr()

    def export(*argv: str) -> tuple[int, str]:
        rc = cli.main(["export", *argv])
        return rc, capsys.readouterr().err.strip()

    mine = tmp_path / "precious.txt"
    mine.write_text("mine\n")
    assert export(str(short), "--out", str(mine)) == (
        2, f"willmore-nlp: error: --out {mine}: exists; --overwrite replaces it, or choose another name")
    assert mine.read_text() == "mine\n"
    assert export(str(short), "--out", str(mine), "--overwrite") == (0, "")
    np.testing.assert_array_equal(load_mesh(mine).vertices, load_run(short).states[-1].vertices)

    record = {p: p.read_bytes() for p in long_run.rglob("*") if p.is_file()}
    for out, overwrite in ((long_run / "states" / "state_000001.npz", True), (long_run / "states" / "state_000009.npz",
                           False), (long_run / "mesh.npz", True), (long_run / "solver_state.npz", False),
                           (long_run / "states", True), (long_run, True), (long_run / "states" / "vtk", False),
                           (long_run / "states" / ".." / "states" / "x.txt", False)):
        rc, err = export(str(short), "--out", str(out), *(["--overwrite"] if overwrite else []))
        assert rc == 2 and err.startswith(f"willmore-nlp: error: --out {out}: is part of the run directory "
                                          f"{long_run} (its record of the run, which export never writes, even with "
                                          "--overwrite)") and "\n" not in err, err
    assert {p: p.read_bytes() for p in long_run.rglob("*") if p.is_file()} == record
    assert export(str(short), "--out", str(long_run / "final.txt"))[0] == 0  # beside the record: allowed

    vtk = tmp_path / "vtk"
    assert export(str(long_run), "--out", str(vtk)) == (0, "")
    (vtk / "notes.txt").write_text("mine")
    (vtk / "state_000099.vtu").write_text("mine, not listed in run.pvd")
    before = {p.name: p.read_bytes() for p in vtk.iterdir()}
    assert export(str(short), "--out", str(vtk)) == (
        2, f"willmore-nlp: error: --out {vtk}: folder exists and is not empty; --overwrite replaces the run.pvd and "
           "state_*.vtu files of an earlier export there (other files stay), or choose another --out")
    assert {p.name: p.read_bytes() for p in vtk.iterdir()} == before
    assert export(str(short), "--out", str(vtk), "--overwrite") == (0, "")
    assert sorted(p.name for p in vtk.iterdir()) == ["notes.txt", "run.pvd", "state_000000.vtu", "state_000001.vtu",
                                                     "state_000099.vtu"]
    assert [ds.get("file") for ds in ET.parse(vtk / "run.pvd").getroot().iter("DataSet")] == [
        "state_000000.vtu", "state_000001.vtu"]
    others = tmp_path / "others"
    others.mkdir()
    (others / "run.txt").write_text("mine")
    assert export(str(short), "--out", str(others), "--overwrite") == (
        2, f"willmore-nlp: error: --out {others}: folder is not empty and holds no earlier export (no run.pvd), so "
           "even --overwrite does not write into it; choose a new or empty folder")
    assert [p.name for p in others.iterdir()] == ["run.txt"]


def test_a_state_in_a_format_of_the_other_kind_names_the_formats_it_has(tmp_path, capsys) -> None:
    """Found by a new-user check (2026-12-01): ``export CURVE_RUN --out c.obj`` said only ".obj holds triangle
    surfaces only", not what a curve exports to. The line now names the curve formats (text curves and npz), and a
    surface to a text curve names the surface formats; exit 2 and nothing written."""
    from willmore_nlp import cli

    curve, surface = tmp_path / "curve", tmp_path / "surface"
    assert cli.main(["run", "circle", "--set", "n=12", "--out", str(curve), "--steps", "1", "--quiet"]) == 0
    assert cli.main(["run", "sphere", "--set", "subdivisions=1", "--out", str(surface), "--steps", "1",
                     "--quiet"]) == 0
    capsys.readouterr()
    for run_dir, name, text in (
            (curve, "c.obj", ".obj holds triangle surfaces only; a curve is written as .txt, .curve, .xy, .xyz (a text "
                             "curve) or .npz"),
            (curve, "c.stl", ".stl holds triangle surfaces only; a curve is written as .txt, .curve, .xy, .xyz (a text "
                             "curve) or .npz"),
            (surface, "s.txt", "the text curve format holds curves only; a surface is written as .obj, .ply, .off, "
                               ".stl or .npz")):
        assert cli.main(["export", str(run_dir), "--out", str(tmp_path / name)]) == 2
        assert capsys.readouterr().err.strip() == f"willmore-nlp: error: {tmp_path / name}: {text}"
        assert not (tmp_path / name).exists()
