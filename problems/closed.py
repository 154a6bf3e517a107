"""Closed curves and surfaces of the paper's Sec. 5.1 (Figs. 2-7, Table 1)."""

from __future__ import annotations

from willmore_nlp.flow import REPAIR_PASSES_HANDLES
from willmore_nlp.mesh import shapes
from willmore_nlp.registry import Problem, register


def _steps(h: float, tau: float | None, tau_tilde: float | None, tt_factor: float = 1.0) -> tuple[float, float]:
    """Defaults tau = h and tau_tilde = tt_factor * h^2 (docs/theory/tau_tilde.md: keep tau_tilde <= h^2)."""
    return (h if tau is None else float(tau)), (tt_factor * h * h if tau_tilde is None else float(tau_tilde))


@register("circle")
def circle(n: int = 200, R: float = 2.0, tau: float | None = None, tau_tilde: float | None = None,
           lam: float = 0.0, t_end: float = 0.1) -> Problem:
    """Circle of radius R expanding by Willmore flow, R(t) = (R^4 + 2t)^(1/4) (Fig. 2, Table 1).

    Defaults: 200 vertices, R(0) = 2, tau = h, tau_tilde = h^2 (the paper's Fig. 2 used
    tau_tilde = h, which docs/theory/tau_tilde.md warns against for non-symmetric shapes).
    """
    mesh = shapes.regular_polygon(n, R)
    tau_, tt_ = _steps(mesh.h, tau, tau_tilde)
    return Problem(mesh, tau_, tt_, lam, t_end=t_end, description="circle expanding under Willmore flow")


@register("sphere")
def sphere(subdivisions: int = 3, radius: float = 1.0, tau: float | None = None,
           tau_tilde: float | None = None, lam: float = 0.0, steps: int = 50) -> Problem:
    """Round sphere, a stationary solution: long-time stability and mesh quality (Fig. 3).

    Icosphere with 10*4^s + 2 vertices (642 for s = 3), tau = h, tau_tilde = h^2 / 100 (the scheme
    shrinks spheres at rate 16 tau_tilde / R^5, so tau_tilde must be small; see docs/theory/tau_tilde.md).
    """
    mesh = shapes.icosphere(subdivisions, radius)
    tau_, tt_ = _steps(mesh.h, tau, tau_tilde, 0.01)
    return Problem(mesh, tau_, tt_, lam, steps=steps, description="sphere stays a sphere")


@register("hypocycloid")
def hypocycloid(n: int = 200, tau: float | None = None, tau_tilde: float | None = None,
                lam: float = 0.025, steps: int = 200) -> Problem:
    """Planar hypocycloid (delta = 0) evolving to a fivefold circle of radius 1/sqrt(2 lam) (Fig. 4).

    The paper used lam = 0.025 and tau = h; the limit radius is 1/sqrt(0.05) = 4.472.
    tau_tilde = h^2 / 100 keeps the O(tau_tilde) shift of the limit radius small.
    """
    mesh = shapes.hypocycloid(n, 0.0)
    tau_, tt_ = _steps(mesh.h, tau, tau_tilde, 0.01)
    return Problem(mesh, tau_, tt_, lam, steps=steps, description="planar hypocycloid to a fivefold circle")


@register("hypocycloid3d")
def hypocycloid3d(n: int = 400, delta: float = 0.1, tau: float | None = None,
                  tau_tilde: float | None = None, lam: float = 0.025, steps: int = 400) -> Problem:
    """Hypocycloid perturbed out of the plane (delta = 0.1) unfolding to a single circle (Fig. 5).

    The paper used h = tau = 0.005 (a very fine curve); the default here is 400 vertices,
    tau = h. lam is not stated in the paper for Fig. 5; 0.025 keeps the limit circle bounded.
    """
    mesh = shapes.hypocycloid(n, delta)
    tau_, tt_ = _steps(mesh.h, tau, tau_tilde, 0.01)
    return Problem(mesh, tau_, tt_, lam, steps=steps, description="hypocycloid in R^3 unfolding to a circle")


@register("torus")
def torus(R: float = 1.0, r: float = 0.5, n_major: int = 24, n_minor: int = 12, tau: float = 1e-3,
          tau_tilde: float | None = None, lam: float = 0.0, t_end: float = 0.1,
          tangential_weight: float = 10.0) -> Problem:
    """Coarse torus of revolution flowing toward the Clifford torus (R/r = sqrt 2, w = 4 pi^2; Figs. 6-7).

    ``tangential_weight`` (default 10; 1 is the paper's scheme) charges the tangential part of the step's distance:
    the scheme's tangential freedom lets a mesh-scale mode (the highest azimuthal wavenumber) grow near the Clifford
    torus and the flow then drifts below sqrt 2 (docs/guide/mesh_quality_measurements.md, "The torus with
    tangential_weight 10": on 48x24 to t = 0.5 R/r 1.396 against 1.316 with weight 1). It gets
    ``conformal_gauge = true`` (not with an area term ``lam``, :meth:`~willmore_nlp.registry.Problem.effective_options`;
    without it the 48x24 torus leaves the tori of revolution: its 8 sector circles spread to R/r 1.11-1.77 by t = 1) and
    ``remesh_repair`` = :data:`~willmore_nlp.flow.REPAIR_PASSES_HANDLES` (4): to t = 1 on 48x24 the lowest W is then
    0.31 % below the grid's Clifford torus (0.68 % with 2 passes), R/r by circle fit 1.402-1.421 from t = 0.1, every
    state >= 15.5 deg, no retry (docs/guide/mesh_quality.md, "Tori and genus 2: four repair passes"). ``--set
    conformal_gauge=false --set remesh_repair=2`` gives the defaults before 2026-11-29.
    """
    mesh = shapes.torus(R, r, n_major, n_minor)
    tau_, tt_ = _steps(mesh.h, tau, tau_tilde, 0.01)
    # (the gauge is dropped where the energy is not Moebius invariant: Problem.effective_options)
    options = {"tangential_weight": float(tangential_weight), "remesh_repair": REPAIR_PASSES_HANDLES,
               "conformal_gauge": True}
    return Problem(mesh, tau_, tt_, lam, t_end=t_end, flow_options=options,
                   description="torus toward the Clifford torus")
