"""Refinement where the mesh no longer resolves the surface (``refine_dihedral``, docs/guide/mesh_quality.md "Folds").

The ellipsoid 1:1:2 of an icosphere(2) (162 v) has adjacent normals turning by up to 21.8 deg; its first step
sharpens its tips a little. With ``refine_dihedral`` below that, the step is followed by a remeshing toward the
edge / sqrt 2: with ``refine_local = false`` of the whole mesh (about twice the vertices), by default of the region
around the sharp edges only; the largest turn smaller, tau_tilde following h^2 for ``steps_from_h``.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from willmore_nlp import WillmoreFlow, geometry
from willmore_nlp import remesh as rm
from willmore_nlp.boundary import Boundary
from willmore_nlp.errors import UserInputError
from willmore_nlp.flow import LOCAL_REFINE_ANGLE, LOCAL_RINGS, REFINE_FACTOR, _movable_turns
from willmore_nlp.mesh import Mesh, shapes
from willmore_nlp.mesh.io import save_mesh
from willmore_nlp.mesh.topology import edge_triangles


def _ellipsoid():
    base = shapes.icosphere(2)
    return base.with_vertices(base.vertices * [1.0, 1.0, 2.0])


def test_a_step_that_sharpens_an_edge_past_refine_dihedral_refines_the_mesh() -> None:
    """refine_dihedral = 15, refine_local = false: step 1 sharpens the tips past it and the whole mesh is refined
    (162 -> 306 v, the mean edge by about 1 / sqrt 2), with a warning naming the counts and edges; on the refined
    state no edge turns by 15 deg, tau_tilde scales with h^2 (steps_from_h = "both"), the Willmore energy moves by
    under 2 % (a finer mesh of the same surface), and the next steps, which sharpen no edge past the limit, do not
    refine again."""
    mesh = _ellipsoid()
    tt = mesh.h**2 / 100
    flow = WillmoreFlow(mesh, mesh.h, tt, refine_dihedral=15, steps_from_h="both", refine_local=False)
    with pytest.warns(UserWarning, match=r"step 1: the mesh was refined \(162 -> \d+ vertices, mean edge ") as w:
        first = flow.step()
    assert first.remeshed.split("+")[-1] == "refine"
    n = len(first.vertices)
    assert 1.6 * 162 < n < 2.4 * 162
    h_old, h_new = (float(v) for v in re.search(r"mean edge (\S+) -> (\S+)\)", str(w[-1].message)).groups())
    assert h_new == pytest.approx(flow.mesh.h, rel=1e-2) and h_new / h_old == pytest.approx(1 / REFINE_FACTOR, rel=0.1)
    assert first.tau_tilde == pytest.approx(tt * (h_new / h_old) ** 2, rel=2e-2)
    assert abs(first.willmore / first.stats["willmore_before_remesh"] - 1) < 0.02
    assert first.quality["max_dihedral"] < 15
    rest = flow.run(steps=2)
    assert all("refine" not in r.remeshed for r in rest) and {len(r.vertices) for r in rest} == {n}


def _half_fine_ellipsoid() -> Mesh:
    """The ellipsoid 1:1:2 of an icosphere(1) with its lower half (z < 0) remeshed toward half its edge (91 v): the
    upper half's edges turn by up to 50 deg, the lower half's by 14 deg or less."""
    base = shapes.icosphere(1)
    V = base.vertices * [1.0, 1.0, 2.0]
    r = rm.isotropic_remesh(V, base.simplices, rm.equilateral_edge(V, base.simplices) / 2, V[:, 2] < 0)
    return Mesh(r.vertices, rm.delaunay_flips(r.vertices, r.simplices)[0])


def _kept_rows(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """(len(A),) bool: the rows of A that are rows of B bit for bit."""
    rows = {a.tobytes() for a in B}
    return np.array([a.tobytes() in rows for a in A])


def test_a_local_refinement_remeshes_only_the_region_of_the_sharp_edges() -> None:
    """refine_dihedral = 25 on the half-fine ellipsoid: step 1 sharpens the coarse upper tip past it. The default
    (refine_local) remeshes the edges sharper than 0.6 x 25 deg and two rings around them toward their edge / sqrt 2:
    the stepped state's vertices outside that region (all in the fine lower half on this small mesh) are
    kept bit for bit and the others are new, the largest turn drops below 25 deg, the Willmore energy moves by under
    5 %, tau_tilde halves (steps_from_h = "both"), the warning says where; the global refinement keeps no vertex."""
    mesh = _half_fine_ellipsoid()
    tt = mesh.h**2 / 100
    opts = {"refine_dihedral": 25, "steps_from_h": "both"}
    stepped = WillmoreFlow(mesh, mesh.h, tt, **{**opts, "refine_dihedral": 180}).step()  # the state refined below
    with pytest.warns(UserWarning, match=r"step 1: the mesh was refined \(near its sharp edges, 91 -> \d+ vertices"):
        local = WillmoreFlow(mesh, mesh.h, tt, **opts).step()
    glob = WillmoreFlow(mesh, mesh.h, tt, **opts, refine_local=False).step()
    assert local.remeshed.split("+")[-1] == glob.remeshed.split("+")[-1] == "refine"
    X, F = stepped.vertices, stepped.simplices
    pairs, ends = edge_triangles(F)
    region = np.zeros(len(X), bool)
    region[ends[geometry.dihedral_angles(X, F, pairs) > LOCAL_REFINE_ANGLE * 25]] = True
    for _ in range(LOCAL_RINGS):
        region[F[region[F].any(axis=1)]] = True
    kept = _kept_rows(X, local.vertices)
    assert np.array_equal(kept, ~region) and kept.sum() >= 10 and (X[kept, 2] < 0).all()  # in the fine half
    assert not _kept_rows(X, glob.vertices).any()
    assert local.quality["max_dihedral"] < 25 < stepped.quality["max_dihedral"]
    assert abs(local.willmore / local.stats["willmore_before_remesh"] - 1) < 0.05
    assert local.tau_tilde == pytest.approx(tt / REFINE_FACTOR**2, rel=1e-12)


def test_a_clamped_surface_is_refined_locally_around_its_free_sharp_edges() -> None:
    """The half-fine ellipsoid clamped on a side of its fine half (x > 0.7, z < 0; 15 fixed vertices), refine_dihedral
    = 25: step 1 sharpens edges past it and the region of the edges sharper than 0.6 x 25 deg that have a free
    vertex's triangle, grown by two rings, is remeshed; its free vertices only: the fixed vertices are kept bit for
    bit and are exactly the refined mesh's fixed ones, the new vertices are free, the largest turn of the patch
    falls, tau_tilde halves, and the flow steps on."""
    mesh = _half_fine_ellipsoid()
    V = mesh.vertices
    bd = Boundary(~((V[:, 0] > 0.7) & (V[:, 2] < 0)))
    tt = mesh.h**2 / 100
    opts = {"boundary": bd, "refine_dihedral": 25, "steps_from_h": "both"}
    plain = WillmoreFlow(mesh, mesh.h, tt, **{**opts, "refine_dihedral": 180})
    stepped = plain.step()
    flow = WillmoreFlow(mesh, mesh.h, tt, **opts)
    with pytest.warns(UserWarning, match=r"step 1: the mesh was refined \(near its sharp edges, 91 -> \d+ vertices"):
        local = flow.step()
    assert local.remeshed.split("+")[-1] == "refine" and (~bd.free).sum() == 15
    X, F, free = stepped.vertices, stepped.simplices, plain.boundary.free
    turn, ends = _movable_turns(X, F, free)
    region = np.zeros(len(X), bool)
    region[ends[turn > LOCAL_REFINE_ANGLE * 25]] = True
    for _ in range(LOCAL_RINGS):
        region[F[region[F].any(axis=1)]] = True
    assert (region & ~free).any()  # the region reaches the clamp, whose vertices stay
    assert np.array_equal(_kept_rows(X, local.vertices), ~(region & free))
    fixed = ~flow.boundary.free
    assert np.array_equal(local.vertices[fixed], X[~free]) and np.array_equal(X[~free], V[~bd.free])
    assert _movable_turns(local.vertices, local.simplices, ~fixed)[0].max() < turn.max()
    assert local.tau_tilde == pytest.approx(tt / REFINE_FACTOR**2, rel=1e-12)
    nxt = flow.step()
    assert np.array_equal(nxt.vertices[~flow.boundary.free], V[~bd.free])


def test_a_locally_refined_mesh_is_remeshed_locally(monkeypatch: pytest.MonkeyPatch) -> None:
    """After a local refinement the mesh is graded: a threshold remeshing (here remesh_min_angle = 44, above the
    refined state's smallest angle) remeshes the triangles below it and two rings around them (a part of the mesh),
    toward the equilateral edge of the triangles at their vertices, and keeps the other vertices bit for bit; the same
    state with refine_local = false is remeshed whole (no vertex kept). (Whether the flow keeps the result depends on
    its quality, as for every remeshing.) The graded mesh's edge-ratio test is within each triangle."""
    mesh = _half_fine_ellipsoid()
    tt = mesh.h**2 / 100
    first = WillmoreFlow(mesh, mesh.h, tt, refine_dihedral=25).step()
    assert first.remeshed.split("+")[-1] == "refine" and first.quality["min_angle"] < 44
    history = [{"step": 0, "remesh_action": ""}, {"step": 1, "remesh_action": first.remeshed}]
    calls: list[tuple[np.ndarray, np.ndarray, float, np.ndarray | None, rm.Remeshed]] = []
    remesh = rm.isotropic_remesh

    def spy(V: np.ndarray, F: np.ndarray, target: float, free: np.ndarray | None = None, **kw: object) -> rm.Remeshed:
        calls.append((np.array(V), np.array(F), target, None if free is None else np.array(free),
                      remesh(V, F, target, free, **kw)))
        return calls[-1][4]

    monkeypatch.setattr(rm, "isotropic_remesh", spy)
    for local in (True, False):
        calls.clear()
        flow = WillmoreFlow(mesh, mesh.h, tt, refine_dihedral=25, remesh_min_angle=44, refine_local=local,
                            input_repair=False)
        flow.restart(first.vertices, first.Y, first.t, 1, simplices=first.simplices, history=history)
        flow.step()
        assert flow._graded() is local and len(calls) == 1
        V, F, target, free, r = calls[0]
        kept = _kept_rows(V, r.vertices)
        if local:
            assert 0.2 * len(V) < (~free).sum() < len(V) and np.array_equal(kept, ~free)
            # the region is the vertices of the triangles below some angle >= 44 deg (44 plus the step's fall of the
            # smallest angle) grown by two rings, the target the equilateral edge of the triangles at those vertices
            angles = geometry.min_angles(V, F)
            found = []
            for limit in np.unique(angles[angles >= 44]):
                start = np.zeros(len(V), bool)
                start[F[angles < limit]] = True
                region = start.copy()
                for _ in range(LOCAL_RINGS):
                    region[F[region[F].any(axis=1)]] = True
                if np.array_equal(region, free):
                    found.append(rm.equilateral_edge(V, F, start))
            assert found and min(abs(np.array(found) / target - 1)) < 1e-12
        else:
            assert free is None and not kept.any()
    q = geometry.triangle_quality(first.vertices, first.simplices, graded=True)
    assert q["edge_ratio"] < geometry.triangle_quality(first.vertices, first.simplices)["edge_ratio"]


def test_below_refine_dihedral_nothing_changes() -> None:
    """The default (100 deg, never reached here) and refine_dihedral = 180 (off) give the same states bit for bit;
    refine_max_vertices below twice the vertex count keeps the mesh even past the limit."""
    mesh = _ellipsoid()
    runs = [WillmoreFlow(mesh, mesh.h, mesh.h**2 / 100, **o).run(steps=2)
            for o in ({}, {"refine_dihedral": 180}, {"refine_dihedral": 15, "refine_max_vertices": 300})]
    for a, b, c in zip(*runs, strict=True):
        assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.vertices, c.vertices)
        assert "refine" not in c.remeshed


def test_the_refinement_options_are_checked() -> None:
    mesh = _ellipsoid()
    for bad in ({"refine_dihedral": 0}, {"refine_dihedral": 181}, {"refine_max_vertices": -1}, {"refine_local": 2}):
        with pytest.raises(UserInputError, match=next(iter(bad))):
            WillmoreFlow(mesh, mesh.h, mesh.h**2 / 100, **bad)


@pytest.mark.parametrize("clamped", [False, True])
def test_a_run_that_refined_resumes_bit_for_bit(tmp_path: Path, straight_and_resumed, clamped: bool) -> None:
    """A user's file with refine_dihedral = 15: 3 steps straight, or 1 step (refined) then --resume to 3, give the
    same states, Y, vertex counts and tau_tilde; the run directory records the action "refine" and its scope. Clamped:
    the genus-2 blending (1,037 v) with refine_dihedral = 32, refined locally at step 2, 4 steps or 2 + 2."""
    if clamped:
        args, total, first, at = ["genus2_blending", "--set", "refine_dihedral=32"], 4, 2, 2
    else:
        save_mesh(_ellipsoid(), tmp_path / "ell.obj")
        args, total, first, at = [str(tmp_path / "ell.obj"), "--set", "refine_dihedral=15"], 3, 1, 1
    a, b = straight_and_resumed(args, total, first, tmp_path)
    assert "refine" in str(a.history[at]["remesh_action"]).split("+")
    assert json.loads((tmp_path / "part" / "config.json").read_text())["refine_scope"] == "local"
    assert [float(h["tau_tilde"]) for h in a.history] == [float(h["tau_tilde"]) for h in b.history]
    for ya, yb, sa, sb in zip(a.Y, b.Y, a.states, b.states, strict=True):
        assert np.array_equal(sa.vertices, sb.vertices) and np.array_equal(sa.simplices, sb.simplices)
        assert np.array_equal(ya, yb)
