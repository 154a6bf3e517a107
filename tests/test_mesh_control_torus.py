"""Rotational symmetry of torus flows: the mesh-scale instability of the paper's scheme near the Clifford torus and
the in-step tangential weight that suppresses it (docs/guide/mesh_quality_measurements.md, 'What breaks the rotational
symmetry')."""

from __future__ import annotations

import numpy as np
import pytest

from willmore_nlp import WillmoreFlow, remesh
from willmore_nlp.analysis import (
    clifford_reference,
    conformal_ratios,
    rigid_align,
    sector_ratios,
    surface_distance,
    torus_fit,
    torus_frame,
    torus_grid_asymmetry,
    torus_grid_asymmetry_wavenumber,
    torus_projection,
)
from willmore_nlp.geometry import triangle_quality, willmore_energy
from willmore_nlp.mesh import Mesh, shapes


@pytest.mark.parametrize("k", [1, 5, 12])
def test_asymmetry_wavenumber_finds_the_mode(k: int) -> None:
    """A perturbation eps cos(k u) of the distance from the axis on the 24x12 grid is found at wavenumber k; for
    k > 1 the asymmetry is its standard deviation over the 24 copies, eps / sqrt 2 (eps at k = 12, where
    cos(12 u) = +-1); k = 1 also shifts the centroid about which it is measured. The grid itself has none."""
    m = shapes.torus(1.0, 0.5, 24, 12)
    X = np.array(m.vertices)
    u = 2 * np.pi * (np.arange(len(X)) // 12) / 24
    eps = 1e-4
    X[:, :2] *= (1 + eps * np.cos(k * u) / np.hypot(X[:, 0], X[:, 1]))[:, None]
    assert torus_grid_asymmetry(m.vertices, 24, 12) < 1e-14
    assert torus_grid_asymmetry_wavenumber(X, 24, 12) == k
    if k > 1:
        assert torus_grid_asymmetry(X, 24, 12) == pytest.approx(eps * (1.0 if k == 12 else np.sqrt(0.5)), rel=1e-6)
    assert torus_grid_asymmetry_wavenumber(X[:-1], 24, 12) == -1


def test_the_step_at_the_clifford_grid_amplifies_the_mesh_scale_mode() -> None:
    """From the 24x12 grid on the Clifford torus (r = 0.5, tau = 1e-3) perturbed by 1e-8 r (seeded: round-off alone
    seeds the mode in some environments and not in others), the first step of the paper's scheme leaves the 24-fold
    symmetry to 0.046 r in the mode of wavenumber 12 (neighbouring meridians apart): the symmetric step is not the
    step's minimiser. tangential_weight = 10 (normal velocity unchanged) takes it less far (0.017 r), but the mode
    grows from the same 6e-9 with it too (measured: 4.6e-2 / 1.7e-2)."""
    g = shapes.torus(np.sqrt(2), 1.0, 24, 12)
    rng = np.random.default_rng(0)
    mesh = g.with_vertices(g.vertices / 2 + 0.5e-8 * rng.standard_normal(g.vertices.shape))
    a0 = torus_grid_asymmetry(mesh.vertices, 24, 12)
    a = {}
    for weight in (1.0, 10.0):
        X = WillmoreFlow(mesh, 1e-3, 0.01 * mesh.h**2, mesh_control="off", tangential_weight=weight).run(steps=1)
        a[weight] = torus_grid_asymmetry(X[-1].vertices, 24, 12)
        assert torus_grid_asymmetry_wavenumber(X[-1].vertices, 24, 12) == 12
    assert a[1.0] > 0.05 * 0.5 > 1e6 * a0
    assert 1e6 * a0 < a[10.0] < 0.5 * a[1.0]


def test_torus_measures_against_exact_tori() -> None:
    """The Figs. 6-7 measures on exact tori: the circle fit and the conformal R/r return the torus's R/r (to
    round-off; the torus shifted in x3), the mesh-matched Clifford reference of a shifted, scaled grid Clifford torus
    is the grid Clifford torus (W is scale invariant), a small rigid motion is undone, and the
    distance between two concentric spheres is their radius difference up to the chord sagitta."""
    m = shapes.torus(1.3, 0.5, 48, 24)
    V = m.vertices + np.array([0.0, 0.0, 0.2])
    R, r = torus_fit(V)
    assert (R, r) == (pytest.approx(1.3, abs=1e-12), pytest.approx(0.5, abs=1e-12))
    assert conformal_ratios(V) == pytest.approx(1.3 / 0.5, rel=1e-9)
    cliff = shapes.torus(np.sqrt(2) * 0.4, 0.4, 48, 24)
    grid = willmore_energy(shapes.torus(np.sqrt(2), 1.0, 48, 24))
    assert clifford_reference(cliff.vertices - np.array([0.0, 0.0, 0.3]), cliff.simplices) == pytest.approx(
        grid, rel=1e-12)
    E = shapes.icosphere(3).vertices * np.array([1.0, 0.7, 0.4])  # no rotational symmetry
    c, s = np.cos(0.05), np.sin(0.05)  # moves points by < h/2 (at 0.1 the closest-vertex iteration stalls)
    moved = E @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ np.array(
        [[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]]) + np.array([0.3, -0.1, 0.05])
    assert np.abs(rigid_align(moved, E) - E).max() < 1e-12
    sph = shapes.icosphere(3)
    d = surface_distance(sph.vertices, sph.simplices, 1.1 * sph.vertices, sph.simplices)
    assert 0.1 <= d <= 0.1 + 1.1 * sph.h**2



def test_torus_frame_undoes_a_rigid_motion_that_the_fixed_axis_measures_misread() -> None:
    """The 48x24 Clifford torus (r = 0.5) tilted by 3 deg and moved by (0.2, -0.1, 0.02): ``torus_frame`` returns
    the planted centre, axis, R and r, and in its frame the sectors, the conformal R/r and the Clifford reference are
    those of the torus at the origin (the grid Clifford torus's W); the circle fit about x3 through the origin and
    the sectors about the vertex centroid (the vertices of one side repeated: a lopsided node density) read shapes
    that are not there."""
    m = shapes.torus(np.sqrt(2) * 0.5, 0.5, 48, 24)
    c, s = np.cos(np.radians(3)), np.sin(np.radians(3))
    shift = np.array([0.2, -0.1, 0.02])
    V = m.vertices @ np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]]).T + shift
    U, centre, axis, R, r, d = torus_frame(V)
    assert np.allclose(centre, shift, atol=1e-10) and abs(axis @ [0.0, -s, c]) == pytest.approx(1.0, abs=1e-12)
    assert (R, r) == (pytest.approx(np.sqrt(2) * 0.5, abs=1e-10), pytest.approx(0.5, abs=1e-10))
    assert np.abs(d).max() < 1e-10
    assert sector_ratios(U, centred=True) == pytest.approx(np.sqrt(2), rel=1e-9)
    assert conformal_ratios(U, centred=True) == pytest.approx(np.sqrt(2), rel=1e-9)
    assert clifford_reference(U, m.simplices) == pytest.approx(willmore_energy(m), rel=1e-9)
    R0, r0 = torus_fit(V)
    assert abs(R0 / r0 - np.sqrt(2)) > 0.02
    assert abs(clifford_reference(V, m.simplices) / willmore_energy(m) - 1) > 0.1
    lopsided = np.vstack([V, V[V[:, 0] > shift[0] + 0.3]])
    assert np.ptp(sector_ratios(lopsided)) > 0.1
    assert np.ptp(sector_ratios(torus_frame(lopsided)[0], centred=True)) < 1e-9


def test_the_isotropic_remeshing_anticipates_the_fall_of_the_smallest_angle(monkeypatch) -> None:
    """The 24x12 torus (tau = 4e-3 to t = 0.05): the grid's inner triangles flatten every step, and a remeshing
    triggered only below remesh_min_angle comes after a stepped state of 12.4 deg; anticipating the step's fall of
    the smallest angle remeshes while the stepped states are still above 15 deg."""
    def stepped_angles(flow: WillmoreFlow) -> tuple[list[float], int]:
        rows: list[dict] = []
        flow.run(t_end=0.05, callback=lambda r: rows.append(r.row()))
        remeshed = sum("remesh" in x["remesh_action"].split("+") for x in rows)
        return [x["min_angle_before_remesh"] if x["remeshed"] else x["q_min_angle"] for x in rows], remeshed

    mesh = shapes.torus(1.0, 0.5, 24, 12)
    new, n_new = stepped_angles(WillmoreFlow(mesh, 4e-3, mesh.h ** 2 / 100))
    assert n_new >= 1 and min(new) >= 15.0
    plain = WillmoreFlow._needs_repair
    monkeypatch.setattr(WillmoreFlow, "_needs_repair", lambda self, X, F, margin=0.0: plain(self, X, F))
    old, n_old = stepped_angles(WillmoreFlow(mesh, 4e-3, mesh.h ** 2 / 100))
    assert n_old >= 1 and min(old) < 15.0


def test_the_discrete_energy_of_the_clifford_torus_depends_on_its_mesh_by_more_than_half_a_percent() -> None:
    """The grid Clifford torus that issue 14's 0.5 % band is measured against is one mesh among many of the same
    shape and size (mesh_quality_measurements.md, 'Why a 0.5 % band ...'): on the 48x24 grid (1,152 v) its smallest
    angle is 11.7 deg, below the 15-deg bound, and W = 39.016; on the 34x34 grid (1,156 v, 22.4 deg) 39.182; on an
    isotropic remesh (about 1,140 v) with its vertices put back on the torus 39.24; on the stretched 64x18 grid
    (1,152 v) 38.724. The energy falls as the triangles stretch along the meridians (more divisions around the axis), by
    more than 0.5 % between meshes of one size; each grid value also converges to 4 pi^2 under refinement (the
    consistency check of the comparison)."""
    R, r = np.sqrt(2) / 2, 0.5
    grid = {ab: shapes.torus(R, r, *ab) for ab in ((64, 18), (48, 24), (34, 34))}
    W = {ab: willmore_energy(m) for ab, m in grid.items()}
    assert triangle_quality(grid[48, 24].vertices, grid[48, 24].simplices)["min_angle"] < 15.0
    m = grid[48, 24]
    iso = remesh.isotropic_remesh(m.vertices, m.simplices, remesh.equilateral_edge(m.vertices, m.simplices, None))
    V = torus_projection(iso.vertices, R, r)
    F, _ = remesh.delaunay_flips(V, iso.simplices)
    w_iso = willmore_energy(Mesh(V, F, "isotropic remesh"))
    assert abs(V.shape[0] / m.n_vertices - 1) < 0.05
    assert triangle_quality(V, F)["min_angle"] > 30.0
    assert W[64, 18] < W[48, 24] < W[34, 34] < w_iso  # the more stretched along the meridians, the lower
    assert W[34, 34] / W[48, 24] - 1 > 0.004 and w_iso / W[48, 24] - 1 > 0.005
    errs = [abs(willmore_energy(shapes.torus(R, r, 2 * k, k)) - 4 * np.pi**2) for k in (12, 24, 48)]
    assert errs[0] > errs[1] > errs[2] and errs[2] < 0.02 * 4 * np.pi**2


def test_the_torus_problem_runs_with_the_gauge_and_four_repair_passes_and_the_fig67_runs_without() -> None:
    """The ``torus`` problem's flow has ``conformal_gauge`` (not with an area term, a spontaneous curvature, an
    anisotropy or a constraint, which make the Moebius motions the flow's own) and ``remesh_repair =
    REPAIR_PASSES_HANDLES``; ``--set`` wins; the Figs. 6-7 runs pin the options their cached runs were made with
    (docs/guide/mesh_quality.md, "Tori and genus 2: four repair passes": on 48x24 to t = 1 the lowest W is 0.31 %
    below the grid's Clifford torus with them, 0.68 % without)."""
    from willmore_nlp import registry
    from willmore_nlp.apps.reproduce import fig67_overrides
    from willmore_nlp.config import resolve
    from willmore_nlp.flow import REPAIR_PASSES_HANDLES

    pb, _ = registry.build("torus")
    s = pb.make_flow().settings
    assert (s.conformal_gauge, s.remesh_repair, s.tangential_weight) == (True, REPAIR_PASSES_HANDLES, 10.0)
    assert REPAIR_PASSES_HANDLES == 4
    s = pb.make_flow(conformal_gauge=False, remesh_repair=2).settings
    assert (s.conformal_gauge, s.remesh_repair) == (False, 2)
    s = registry.build("torus", lam=0.5)[0].make_flow().settings
    assert (s.conformal_gauge, s.remesh_repair) == (False, REPAIR_PASSES_HANDLES)
    # the gauge gives way wherever the energy is not Moebius invariant, unless asked for
    for over in ({"c0": 0.5}, {"anisotropy": "gamma1"}, {"volume": "initial"}):
        assert "conformal_gauge" not in pb.effective_options(over), over
    assert pb.effective_options({"c0": 0.5, "conformal_gauge": True})["conformal_gauge"] is True
    assert pb.effective_options({"c0": 0.0})["conformal_gauge"] is True
    for power in (1, 2):
        spec = resolve("torus", fig67_overrides(power))
        s = spec.problem.make_flow(**spec.flow_options).settings
        assert (s.conformal_gauge, s.remesh_repair, s.rest_dilation) == (False, 2, False)
