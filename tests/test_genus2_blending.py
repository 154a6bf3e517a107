"""Genus 2: the double torus builder, the genus2_blending problem (Fig. 10) and the normal-jump measure."""

import itertools

import numpy as np
import pytest

from willmore_nlp import geometry, registry
from willmore_nlp.analysis import normal_jumps
from willmore_nlp.boundary import boundary_data
from willmore_nlp.mesh import shapes
from willmore_nlp.mesh.core import MeshError
from willmore_nlp.mesh.topology import euler_characteristic


def test_double_torus_is_a_resolved_genus2_surface() -> None:
    """Euler characteristic -2, vertices on the implicit surface (to the marching-cubes grid), and a mesh that
    resolves its curvature (h |H| < 1), unlike the lemniscate surface of shapes.genus2 (h |H| > 1.5)."""
    m = shapes.double_torus(h=0.3, grid=64)
    assert euler_characteristic(m.simplices) == -2
    grid_step = 2 * (1.25 + 1.5 + 0.2 + 0.6) / 63
    assert np.abs(shapes.double_torus_function(m.vertices)).max() < 0.5 * grid_step
    H = np.linalg.norm(geometry.mean_curvature_vector(m), axis=1)
    assert m.h * H.max() < 1.0
    assert geometry.quality(m)["min_angle"] > 25
    with pytest.raises(MeshError, match="double_torus"):
        shapes.double_torus(d=3.0)


def test_normal_jumps_see_a_kink_at_gamma() -> None:
    """On an icosphere the largest normal angle across Gamma is that of the smooth fixed surface next to it;
    a cap pressed flat puts a kink there, and the jump across Gamma exceeds the fixed surface's."""
    m = shapes.icosphere(3)
    V = np.array(m.vertices)
    free = V[:, 2] > 0.8
    smooth = normal_jumps(V, m.simplices, free)
    assert smooth["gamma"] < 1.5 * smooth["fixed"] and smooth["patch"] < 1.5 * smooth["fixed"]
    V[free, 2] = 0.8 + 0.2 * (V[free, 2] - 0.8)
    kinked = normal_jumps(V, m.simplices, free)
    assert kinked["fixed"] == smooth["fixed"]
    assert kinked["gamma"] > 2 * smooth["fixed"]


def test_genus2_blending_keeps_the_ring_fixed_and_lowers_the_energy() -> None:
    """A few steps with the problem's defaults (ring variant, mesh control on): every non-free vertex keeps its
    position bit for bit, the patch Willmore energy falls from the noisy fill, the steps converge."""
    pb, _ = registry.build("genus2_blending", h=0.3, steps=3)
    bd = boundary_data(pb.mesh, pb.flow_options["boundary"])
    assert euler_characteristic(pb.mesh.simplices) == -2
    assert bd.variant == "ring" and bd.ring.any() and bd.free.sum() >= 10
    flow = pb.make_flow()
    w0 = geometry.willmore_energy(pb.mesh, flow.energy_nodes)
    out = flow.run(steps=pb.steps)
    fixed0 = pb.mesh.vertices[~bd.free]
    for r in out:
        assert r.converged
        assert np.array_equal(r.vertices[~r.free], fixed0)
    assert out[-1].willmore < 0.5 * w0
    # energy inequality of each step: e(X^{k+1}) before the repair <= e(X^k) after it
    for a, b in itertools.pairwise(out):
        assert b.stats.get("energy_before_remesh", b.energy) <= a.energy * (1 + 1e-10)
    with pytest.raises(MeshError, match="fill"):
        registry.build("genus2_blending", h=0.3, fill="smooth")


def test_a_remeshing_that_lowers_the_smallest_angle_is_dropped(monkeypatch) -> None:
    """The isotropic remeshing (forced by a 35-degree threshold on the 24x12 torus) is applied when it improves
    the mesh and dropped when its result has a smaller angle than the repaired mesh (a sliver planted in it)."""
    from willmore_nlp import WillmoreFlow
    from willmore_nlp import remesh as rm

    m = shapes.torus(1.0, 0.5, 24, 12)
    out = WillmoreFlow(m, 1e-3, 0.01 * m.h**2, remesh_min_angle=35).run(steps=1)
    assert out[0].remeshed.endswith("remesh") and out[0].quality["min_angle"] > 30
    real = rm.isotropic_remesh

    def sliver(V, F, target, free=None, **kw):
        r = real(V, F, target, free, **kw)
        a, b = r.simplices[0, :2]
        r.vertices[a] = r.vertices[b] + 1e-3 * (r.vertices[a] - r.vertices[b])
        return r

    monkeypatch.setattr(rm, "isotropic_remesh", sliver)
    out = WillmoreFlow(m, 1e-3, 0.01 * m.h**2, remesh_min_angle=35).run(steps=1)
    assert "remesh" not in out[0].remeshed and out[0].vertices.shape == m.vertices.shape
    assert out[0].quality["min_angle"] > 20
