"""Genus 2 toward Lawson's surface: the minimal-S^3 fit, the Moebius maps and the conformal gauge, and a few steps
of the stored start ``shapes.lawson_genus2`` (docs/guide/mesh_quality_measurements.md, "Genus 2")."""

from __future__ import annotations

import numpy as np
import pytest

from willmore_nlp import WillmoreFlow, geometry
from willmore_nlp.analysis import fit_order, minimal_s3_fit
from willmore_nlp.errors import UserInputError
from willmore_nlp.mesh import shapes
from willmore_nlp.mesh.core import Mesh
from willmore_nlp.mesh.topology import euler_characteristic

LAWSON_21 = 2 * 21.9  # Hsu, Kusner, Sullivan 1992: int H^2 = 21.9, H the mean of the principal curvatures


def clifford(n: int) -> tuple[np.ndarray, np.ndarray]:
    t = shapes.torus(np.sqrt(2), 1.0, n, n // 2)
    return t.vertices, t.simplices


def test_minimal_s3_fit_converges_on_clifford_tori_and_rejects_other_tori() -> None:
    res = [minimal_s3_fit(*clifford(n))[2] for n in (24, 48, 96)]
    assert fit_order([1 / 24, 1 / 48, 1 / 96], res) == pytest.approx(2.0, abs=0.1)
    V, F = clifford(48)
    c, rho, r = minimal_s3_fit(0.7 * V + [0.3, -1.0, 2.0], F)  # similarity covariant
    assert np.allclose(c, [0.3, -1.0, 2.0], atol=1e-6) and rho == pytest.approx(0.7 * minimal_s3_fit(V, F)[1])
    assert r == pytest.approx(res[1], rel=1e-6)
    fat = shapes.torus(1.0, 0.5, 48, 24)  # R/r = 2: a torus of revolution that is no such image
    assert minimal_s3_fit(fat.vertices, fat.simplices)[2] > 50 * res[1]


def test_stereographic_reprojection_maps_clifford_to_another_image_of_it() -> None:
    V, F = clifford(48)
    same = geometry.stereographic_reprojection(V, np.zeros(3), 1.0, np.array([0, 0, 0, 1.0]))
    d0 = np.linalg.norm(V[F[:, 0]] - V[F[:, 1]], axis=1)
    assert np.allclose(np.linalg.norm(same[F[:, 0]] - same[F[:, 1]], axis=1), d0)  # a rotation of it
    pole = np.array([0.0, 0.0, 0.3, 1.0])  # not a point of the torus in S^3
    W = geometry.stereographic_reprojection(V, np.zeros(3), 1.0, pole)
    ratio = np.linalg.norm(W[F[:, 0]] - W[F[:, 1]], axis=1) / d0
    assert ratio.std() > 0.1 * ratio.mean()  # not a similarity: a Dupin cyclide
    F2 = F if geometry.enclosed_volume(Mesh(W, F)) > 0 else F[:, ::-1]
    _, _, r = minimal_s3_fit(W, F2)
    assert r < 2 * minimal_s3_fit(V, F)[2]  # still an image of the minimal torus, to the same O(h^2)


def test_conformal_motion_finds_a_special_conformal_step_and_ignores_similarities() -> None:
    t = shapes.double_torus(h=0.3)
    X0 = t.vertices
    centre = X0.mean(0)
    scale = float(np.sqrt(geometry.measure(t) / (4 * np.pi)))
    b = np.array([0.004, -0.002, 0.003])
    X1 = geometry.special_conformal_map(X0, b, centre, scale)
    got, c2, s2 = geometry.conformal_motion(t, X1)
    assert np.allclose(c2, centre) and s2 == pytest.approx(scale)
    assert np.allclose(got, b, rtol=0.03, atol=0)  # a first-order fit with discrete normals
    undone = geometry.special_conformal_map(X1, -got, centre, scale)
    assert np.abs(undone - X0).max() < 0.05 * np.abs(X1 - X0).max()
    # a similarity of the same size (1e-3) has no special conformal part (to second order, 1e-6)
    e = 1e-3
    rot = np.array([[np.cos(e), -np.sin(e), 0], [np.sin(e), np.cos(e), 0], [0, 0, 1]]) @ np.array(
        [[1, 0, 0], [0, np.cos(e), -np.sin(e)], [0, np.sin(e), np.cos(e)]])
    similar = (1 + e) * X0 @ rot.T + [e, 2 * e, -e]
    assert np.abs(geometry.conformal_motion(t, similar)[0]).max() < 1e-5


def test_conformal_gauge_refuses_constraints() -> None:
    m = shapes.icosphere(1)
    with pytest.raises(UserInputError, match="conformal_gauge"):
        WillmoreFlow(m, m.h, 0.01 * m.h**2, conformal_gauge=True, volume="initial")


def test_lawson_start_steps_with_the_gauge() -> None:
    """A few steps of the stored genus-2 start (remeshed coarser): no failed step, min angle >= 15 deg after
    every repair, Euler characteristic -2 kept, the energy falls and stays near Lawson's (557 v: W 43.58 -> 43.02,
    min angle >= 35 deg, no retry)."""
    mesh = shapes.lawson_genus2(0.3)
    assert euler_characteristic(mesh.simplices) == -2 and 450 < mesh.n_vertices < 650
    w0 = geometry.willmore_energy(mesh)
    flow = WillmoreFlow(mesh, mesh.h, 0.01 * mesh.h**2, adaptive=True, max_retries=6, tangential_weight=100.0,
                        conformal_gauge=True)
    results = flow.run(steps=4)
    assert len(results) == 4 and all(r.converged for r in results)
    assert all(r.quality["min_angle"] >= 15.0 for r in results)
    assert all(euler_characteristic(r.simplices) == -2 for r in results)
    assert results[-1].willmore < w0
    assert abs(results[-1].willmore / LAWSON_21 - 1) < 0.03
    assert all(np.isfinite(r.stats["conformal_gauge_shift"]) for r in results)


def test_conformal_motion_on_a_torus_of_revolution_sees_the_cyclide_directions() -> None:
    """On the Clifford torus (48x24) the special conformal fields V_x, V_y (which make cyclides) are found exactly
    from a planted map; V_z's normal component is that of a translation along the axis (r^2 - R^2) sin(theta)
    (the rest is tangential), a near-null direction of the fit that it leaves alone
    (docs/guide/mesh_quality_measurements.md, "The 48x24 torus with the conformal gauge")."""
    t = shapes.torus(np.sqrt(2), 1.0, 48, 24)
    centre, scale = t.vertices.mean(0), float(np.sqrt(geometry.measure(t) / (4 * np.pi)))
    for b in ([1e-3, 0.0, 0.0], [4e-4, -7e-4, 0.0]):
        got = geometry.conformal_motion(t, geometry.special_conformal_map(t.vertices, np.array(b), centre, scale))[0]
        assert np.allclose(got, b, rtol=1e-5, atol=1e-9)
    got = geometry.conformal_motion(t, geometry.special_conformal_map(t.vertices, np.array([0, 0, 1e-3]), centre,
                                                                      scale))[0]
    assert np.abs(got[:2]).max() < 1e-12 and abs(got[2]) < 0.1e-3
