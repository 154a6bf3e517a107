"""Folds: the angle between adjacent triangles' normals, and the step check ``max_dihedral`` that refuses a step
which folds the mesh (triangles of good shape folded onto each other, which the angle and edge-ratio checks do not
see)."""

import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import trimesh

from willmore_nlp import WillmoreFlow, geometry
from willmore_nlp.errors import UserInputError
from willmore_nlp.flow import FlowError
from willmore_nlp.mesh import shapes
from willmore_nlp.mesh.core import Mesh
from willmore_nlp.mesh.io import save_mesh
from willmore_nlp.mesh.topology import edge_triangles
from willmore_nlp.runner import fold_hint, last_reason


@pytest.mark.parametrize("theta", [0.0, 30.0, 90.0, 150.0, 179.0])
def test_the_dihedral_angle_of_a_hinge_is_its_opening(theta: float) -> None:
    """Two unit triangles on the edge (0, 1) along x1, the second rotated about it by theta: their normals turn by
    theta (0 when flat, 180 when folded back)."""
    t = np.radians(theta)
    V = np.array([[0, 0, 0], [1, 0, 0], [0.5, 1, 0], [0.5, -np.cos(t), -np.sin(t)]], float)
    F = np.array([[0, 1, 2], [1, 0, 3]])
    pairs, ends = edge_triangles(F)
    assert ends.tolist() == [[0, 1]] and sorted(pairs[0].tolist()) == [0, 1]
    np.testing.assert_allclose(geometry.dihedral_angles(V, F), [theta], atol=1e-9)


def test_dihedral_angles_agree_with_trimesh() -> None:
    """Every interior edge of a noisy icosphere(2): the same angles as trimesh's face_adjacency_angles (an
    independent implementation), and the largest is the one geometry.quality reports."""
    m = trimesh.creation.icosphere(2)
    V = m.vertices + 0.05 * np.random.default_rng(1).standard_normal(m.vertices.shape)
    ours = geometry.dihedral_angles(V, m.faces)
    theirs = np.degrees(trimesh.Trimesh(V, m.faces, process=False).face_adjacency_angles)
    np.testing.assert_allclose(np.sort(ours), np.sort(theirs), rtol=0, atol=1e-9)
    assert geometry.quality(Mesh(V, m.faces))["max_dihedral"] == pytest.approx(ours.max(), abs=1e-12)


def _folded(mesh: Mesh) -> tuple[np.ndarray, tuple[int, int]]:
    """The vertices of ``mesh`` (a unit sphere) with vertex 0 moved on the sphere across the edge (a, b) of one of
    its triangles, past the edge's middle: the triangle folds back over its neighbour at that edge; and (a, b)."""
    X = mesh.vertices.copy()
    S = mesh.simplices
    a, b = sorted(int(v) for v in S[(S == 0).any(axis=1)][0] if v != 0)
    X[0] += 1.5 * (0.5 * (X[a] + X[b]) - X[0])
    X[0] /= np.linalg.norm(X[0])
    return X, (a, b)


def test_a_fold_is_named_and_an_edge_as_sharp_before_is_allowed() -> None:
    """Vertex 0 of an icosphere(2) moved across the edge of one of its triangles (a fold of 173 deg, every angle
    above 14 deg): the check names the fold at that edge, where it is and the angle; with max_dihedral = 180
    nothing; a step from a state that has the fold already, keeping it or unfolding it, is not refused."""
    mesh = shapes.icosphere(2)
    flow = WillmoreFlow(mesh, 0.01, 1e-4)
    X, (a, b) = _folded(mesh)
    q = geometry.quality(mesh.with_vertices(X))
    assert q["max_dihedral"] > 170 and q["min_angle"] > 14
    reason = flow._fold(X, q)
    near = ", ".join(f"{c:.3g}" for c in (X[a] + X[b]) / 2)
    assert reason is not None and reason.startswith(f"mesh folds: the normals of the triangles at edge ({a}, {b}) "
                                                    f"near ({near}) ")
    assert f"turn by {q['max_dihedral']:.4g} deg > max_dihedral = 120" in reason
    assert WillmoreFlow(mesh, 0.01, 1e-4, max_dihedral=180)._fold(X, q) is None
    flow.X = X
    assert flow._fold(X, q) is None
    assert flow._fold(mesh.vertices, geometry.quality(mesh)) is None


def test_an_input_with_a_fold_is_warned_about() -> None:
    """The folded icosphere of the test above as an input: one warning counts the edges beyond the limit and names
    the sharpest with its angle (the flow keeps them: the check refuses only sharper ones); the icosphere itself
    gives none."""
    mesh = shapes.icosphere(2)
    X, (a, b) = _folded(mesh)
    top = geometry.quality(mesh.with_vertices(X))["max_dihedral"]
    over = int(np.count_nonzero(geometry.dihedral_angles(X, mesh.simplices) > 120))
    with pytest.warns(UserWarning, match=rf"{over} edge\(s\) whose triangles' normals turn by more than max_dihedral "
                      rf"= 120 deg \(most at edge \({a}, {b}\): {top:.4g} deg\)"):
        WillmoreFlow(mesh.with_vertices(X), 0.01, 1e-4, mesh_control="off")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        WillmoreFlow(mesh, 0.01, 1e-4, mesh_control="off")


def test_a_flow_that_must_sharpen_edges_beyond_max_dihedral_fails_with_the_fold_named() -> None:
    """An ellipsoid 1:1:2 (icosphere(2), 162 v; its sharpest edges, 21.8 deg, at the tips) flows toward a sphere:
    the edges of its flat middle, below 12 deg, sharpen beyond 12 deg in a step (checked here with the check off).
    With max_dihedral = 12 every attempt (tau = h, h/2, h/4) is refused as a fold and the step fails naming it:
    the check runs inside the step, with its retries, and only against edges the step sharpened (the tips, above
    12 deg from the start, do not count)."""
    base = shapes.icosphere(2)
    mesh = base.with_vertices(base.vertices * [1.0, 1.0, 2.0])
    F = mesh.simplices
    before = geometry.dihedral_angles(mesh.vertices, F)
    free = WillmoreFlow(mesh, mesh.h, 0.01 * mesh.h**2, mesh_control="off")
    assert free.step().retries == 0
    after = geometry.dihedral_angles(free.X, F)
    assert before.max() > 20 and np.any((before < 12) & (after > 12))
    with pytest.warns(UserWarning, match="turn by more than max_dihedral = 12 deg"):  # the tips: kept, not refused
        flow = WillmoreFlow(mesh, mesh.h, 0.01 * mesh.h**2, max_dihedral=12, max_retries=2, mesh_control="off")
    with pytest.raises(FlowError) as err:
        flow.step()
    assert len(err.value.rejected) == 3 and all("mesh folds" in r for r in err.value.rejected)
    np.testing.assert_array_equal(flow.X, mesh.vertices)


@pytest.mark.parametrize("bad", [0, -5, 181, "x"])
def test_max_dihedral_must_be_an_angle(bad: object) -> None:
    with pytest.raises(UserInputError, match="max_dihedral"):
        WillmoreFlow(shapes.icosphere(1), 0.1, 1e-3, max_dihedral=bad)


def test_the_error_line_names_the_cause_when_the_step_size_floor_ends_a_step(tmp_path: Path) -> None:
    """The ellipsoid of the test above as a user's file with max_dihedral = 12 and min_tau = 0.3 h: the attempts at
    h and h/2 are refused as folds and the next would be below min_tau; the one-line error shows the floor and,
    after it, the fold that caused it (before, only "step size below min_tau"), and what follows such a fold further
    (a remesh_target of half the mean edge)."""
    base = shapes.icosphere(2)
    mesh = base.with_vertices(base.vertices * [1.0, 1.0, 2.0])
    save_mesh(mesh, tmp_path / "ell.obj")
    r = subprocess.run([sys.executable, "-m", "willmore_nlp.cli", "run", str(tmp_path / "ell.obj"), "--out",
                        str(tmp_path / "out"), "--steps", "1", "--quiet", "--set", "max_dihedral=12", "--set",
                        f"min_tau={0.3 * mesh.h}", "--set", "length=1"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 1 and "Traceback" not in r.stderr
    line = r.stderr.strip().splitlines()[-1]
    assert "failed after 3 attempts (last: tau=" in line and ": step size below min_tau = " in line
    assert "; before it: tau=" in line and "mesh folds: the normals of the triangles at edge (" in line
    assert line.endswith(f"a finer mesh from the start resolves a narrower one, e.g. --set remesh_target="
                         f"{mesh.h / 2:.3g} (half the mean edge {mesh.h:.3g})")


def test_the_fold_hint_turns_input_repair_on_where_it_is_off(tmp_path: Path) -> None:
    """The vesicle problem flows its generated starts as given (input_repair = false), so the fold hint's
    ``--set remesh_target=H`` alone gave the identical failure again (v = 0.3 on 162 vertices, a new-user check); it
    now names ``--set input_repair=true`` with it (which remeshes that start to 496 vertices, v kept to 1e-14). The
    step size of the last of the 5 default attempts, taken alone, folds at once. With the mesh control off
    remesh_target does not touch the input at all, and the hint says so instead of naming it."""
    from willmore_nlp.registry import build

    h = build("vesicle", reduced_volume=0.3, subdivisions=2)[0].mesh.h
    r = subprocess.run([sys.executable, "-m", "willmore_nlp.cli", "run", "vesicle", "--out", str(tmp_path / "out"),
                        "--quiet", "--set", "reduced_volume=0.3", "--set", "subdivisions=2", "--set", "tau=0.000273",
                        "--set", "max_retries=0"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 1 and "Traceback" not in r.stderr
    line = r.stderr.strip().splitlines()[-1]
    assert "(last: tau=0.000273: mesh folds: " in line
    assert line.endswith(f"a narrower one, e.g. --set input_repair=true --set remesh_target={h / 2:.3g} (half the "
                         f"mean edge {h:.3g})")
    assert fold_hint(0.33).endswith("e.g. --set remesh_target=0.165 (half the mean edge 0.33)")
    off = fold_hint(0.33, remeshes_input=False, input_repair=False)
    assert "--set" not in off and off.endswith("remesh_target remeshes the input only while mesh_control and remesh "
                                               "are auto)")


def test_last_reason_keeps_a_cause_that_is_the_last_entry() -> None:
    assert last_reason([], "boom") == "boom"
    assert last_reason(["tau=1: solver failed"], "x") == "tau=1: solver failed"
    assert last_reason(["tau=0.5: step size below min_tau = 0.6"], "x") == "tau=0.5: step size below min_tau = 0.6"


def test_a_light_repair_round_that_folds_the_surface_is_not_taken(tmp_path: Path) -> None:
    """A thin trimesh torus (R/r 5, 48 x 12 sections, 576 v, the ``file`` problem) leaves its first step with
    slivers (1.43 deg, edge ratio 40). The light repair's rounds on it folded the surface (normals of adjacent
    triangles 179 degrees apart), the remeshing of that folded state was folded as well, and the fold check then
    dropped the whole repair: with ``refine_dihedral = 180`` no step was repaired and the smallest angle fell to 0.5
    deg (a new user's check; with the default refinement a remeshing of the folded state coarsened the mesh to 146 v).
    A round that folds the surface is now not taken, and the remeshing starts from the last state without the fold:
    the first step's state (taken at the file's tau with ``max_retries = 0``, as the step that collapses the mesh is
    otherwise retried at tau / 2) is remeshed to a healthy mesh (smallest angle >= 20 deg, no edge beyond
    max_dihedral)."""
    from willmore_nlp import registry

    trimesh.creation.torus(major_radius=1.0, minor_radius=0.2, major_sections=48,
                           minor_sections=12).export(tmp_path / "torus.obj")
    pb, _ = registry.build("file", path=str(tmp_path / "torus.obj"))
    flow = pb.make_flow(refine_dihedral=180.0, max_retries=0)  # (the step's only attempt is taken with its slivers)
    r = flow.step()
    assert r.stats["min_angle_before_remesh"] < 2.0 and "remesh" in r.remeshed.split("+")
    X, F = flow.X, flow.mesh.simplices
    assert geometry.min_angles(X, F).min() >= 20.0
    assert geometry.dihedral_angles(X, F).max() < flow.settings.max_dihedral
