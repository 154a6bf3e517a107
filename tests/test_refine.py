"""Refinement where the mesh no longer resolves the surface (``refine_dihedral``, docs/guide/mesh_quality.md "Folds").

The ellipsoid 1:1:2 of an icosphere(2) (162 v) has adjacent normals turning by up to 21.8 deg; its first step
sharpens its tips a little. With ``refine_dihedral`` below that, the step is followed by a remeshing toward the
edge / sqrt 2: about twice the vertices, the largest turn smaller, tau_tilde following h^2 for ``steps_from_h``.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from willmore_nlp import WillmoreFlow
from willmore_nlp.errors import UserInputError
from willmore_nlp.flow import REFINE_FACTOR
from willmore_nlp.mesh import shapes
from willmore_nlp.mesh.io import save_mesh


def _ellipsoid():
    base = shapes.icosphere(2)
    return base.with_vertices(base.vertices * [1.0, 1.0, 2.0])


def test_a_step_that_sharpens_an_edge_past_refine_dihedral_refines_the_mesh() -> None:
    """refine_dihedral = 15: step 1 sharpens the tips past it and the mesh is refined (162 -> 306 v, the mean edge by
    about 1 / sqrt 2), with a warning naming the counts and edges; on the refined state no edge turns by 15 deg,
    tau_tilde scales with h^2 (steps_from_h = "both"), the Willmore energy moves by under 2 % (a finer mesh of the
    same surface), and the next steps, which sharpen no edge past the limit, do not refine again."""
    mesh = _ellipsoid()
    tt = mesh.h**2 / 100
    flow = WillmoreFlow(mesh, mesh.h, tt, refine_dihedral=15, steps_from_h="both")
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
    for bad in ({"refine_dihedral": 0}, {"refine_dihedral": 181}, {"refine_max_vertices": -1}):
        with pytest.raises(UserInputError, match=next(iter(bad))):
            WillmoreFlow(mesh, mesh.h, mesh.h**2 / 100, **bad)


def test_a_run_that_refined_resumes_bit_for_bit(tmp_path: Path, straight_and_resumed) -> None:
    """A user's file with refine_dihedral = 15: 3 steps straight, or 1 step (refined) then --resume to 3, give the
    same states, Y, vertex counts and tau_tilde; the run directory records the action "refine"."""
    save_mesh(_ellipsoid(), tmp_path / "ell.obj")
    a, b = straight_and_resumed([str(tmp_path / "ell.obj"), "--set", "refine_dihedral=15"], 3, 1, tmp_path)
    assert "refine" in str(a.history[1]["remesh_action"]).split("+")
    assert [float(h["tau_tilde"]) for h in a.history] == [float(h["tau_tilde"]) for h in b.history]
    for ya, yb, sa, sb in zip(a.Y, b.Y, a.states, b.states, strict=True):
        assert np.array_equal(sa.vertices, sb.vertices) and np.array_equal(sa.simplices, sb.simplices)
        assert np.array_equal(ya, yb)
