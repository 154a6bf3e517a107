"""The Willmore lower bounds of closed surfaces (Willmore: 8 pi; Marques-Neves: 4 pi^2 for genus >= 1) and the
warning a run prints when its last state lies too far below them (the mesh does not resolve the shape)."""

import subprocess
import sys

import numpy as np
import pytest

from willmore_nlp.geometry import willmore_energy
from willmore_nlp.mesh import shapes
from willmore_nlp.mesh.io import save_mesh
from willmore_nlp.references import RESOLUTION_GAP, resolution_warning, willmore_lower_bound
from willmore_nlp.rundir import load_run


def test_bounds_by_topology_and_the_gap_of_exact_shapes_meshes() -> None:
    """8 pi for a sphere, 4 pi^2 for genus 1 and 2, none for curves and open surfaces; the exact shapes' meshes lie
    below their bound by a gap that shrinks as O(h^2) (the orders of four doubled grids); only coarse ones warn."""
    assert willmore_lower_bound(shapes.icosphere(2))[0] == pytest.approx(8 * np.pi)
    assert willmore_lower_bound(shapes.torus(1.0, 0.5, 16, 8))[0] == pytest.approx(4 * np.pi**2)
    assert "genus 2" in willmore_lower_bound(shapes.lawson_genus2())[1]
    assert willmore_lower_bound(shapes.regular_polygon(32)) is None and willmore_lower_bound(shapes.disk(4)) is None
    sphere = shapes.icosphere(3)
    assert 0 < 1 - willmore_energy(sphere) / (8 * np.pi) < RESOLUTION_GAP and resolution_warning(
        sphere, willmore_energy(sphere)) == ""
    gaps = []
    grids = (12, 24, 48, 96)
    for n in grids:
        clifford = shapes.torus(np.sqrt(2.0), 1.0, n, n // 2)
        w = willmore_energy(clifford)
        gaps.append(1 - w / (4 * np.pi**2))
        assert bool(resolution_warning(clifford, w)) == (gaps[-1] > RESOLUTION_GAP)
    assert gaps[0] > RESOLUTION_GAP > gaps[-1] > 0
    orders = np.log2(np.array(gaps[:-1]) / np.array(gaps[1:]))  # each grid twice as fine as the last
    assert np.all(np.diff(orders) > 0) and 1.9 < orders[-1] < 2.1  # measured 1.63, 1.90, 1.99: O(h^2)


def test_a_run_that_ends_below_the_bound_says_the_mesh_is_too_coarse(tmp_path) -> None:
    """A 12 x 6 torus read from a file and flowed as given (``input_repair=false``; the file problem would refine it as
    a coarse torus) flows below 4 pi^2 within three steps (the Clifford torus on its grid is 13.5 % below): the run
    ends with a one-line warning naming the gap, the vertex count and remesh_target; exit 0. With 2 repair passes:
    with the 4 that file tori get (``flow.REPAIR_PASSES_HANDLES``) this grid folds at step 3 and the run stops there
    (exit 1, naming the fold and a finer ``remesh_target``)."""
    save_mesh(shapes.torus(1.0, 0.5, 12, 6), tmp_path / "t12.obj")
    out = tmp_path / "run"
    r = subprocess.run([sys.executable, "-m", "willmore_nlp.cli", "run", str(tmp_path / "t12.obj"), "--steps", "3",
                        "--set", "input_repair=false", "--set", "remesh_repair=2", "--set", "length=1",
                        "--out", str(out), "--quiet"],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    run = load_run(out)
    last, w = run.states[-1], float(run.history[-1]["willmore_energy"])
    gap = 1 - w / (4 * np.pi**2)
    assert gap > RESOLUTION_GAP
    lines = [line for line in r.stderr.splitlines() if "discretisation error" in line]
    assert len(lines) == 1 and f"{100 * gap:.1f} % below 4 pi^2" in lines[0]
    assert f"on {last.vertices.shape[0]} vertices" in lines[0] and "remesh_target" in lines[0]
