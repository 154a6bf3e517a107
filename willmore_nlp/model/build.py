"""Build the step problem of a mesh from the flow's options: pick the terms (:mod:`willmore_nlp.model.terms`)."""

from __future__ import annotations

from collections.abc import Collection, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from willmore_nlp.anisotropy import Anisotropy, get_anisotropy
from willmore_nlp.boundary import Boundary, BoundaryData, boundary_data
from willmore_nlp.mesh.core import Mesh, MeshError
from willmore_nlp.model.step import StepProblem
from willmore_nlp.model.terms import (
    AnisotropicInner,
    AreaConstraint,
    AreaEnergy,
    Conormal,
    Distance,
    Helfrich,
    IsotropicInner,
    TangentialControlTerm,
    Term,
    VolumeConstraint,
    Willmore,
)
from willmore_nlp.tangential import TangentialControl


@dataclass
class StepSetup:
    """A step problem and what the flow needs to know about it.

    Attributes
    ----------
    problem : StepProblem
    boundary : clamped-boundary data, or None
    anisotropy : the anisotropy, or None
    simplices : (K, d + 1) all simplices of the mesh (the tangential control's neighbourhoods)
    """

    problem: StepProblem
    boundary: BoundaryData | None = None
    anisotropy: Anisotropy | None = None
    simplices: np.ndarray | None = None

    def params(self, Xk: np.ndarray, tau: float, tt: float, lam: float, off: Collection[str] = ()) -> np.ndarray:
        """Parameter vector of a step from Xk (``off``: :meth:`StepProblem.pack_p`)."""
        return self.problem.pack_p(Xk, tau, tt, lam, self.simplices, off)


def build_step(mesh: Mesh, *, boundary: Any = None, anisotropy: Any = None, tangential_weight: float = 1.0,
               tangential_control: TangentialControl | None = None, c0: float = 0.0, volume: float | None = None,
               area: float | None = None, extra_terms: Sequence[Term] = ()) -> StepSetup:
    """The step problem of ``mesh``: the sum of the terms its options select.

    Parameters
    ----------
    mesh : Mesh
        Closed unless ``boundary`` is given.
    boundary : Boundary, optional
        Clamped boundary (:mod:`willmore_nlp.boundary`): the "conormal" variant poses the inner
        problem on the patch with the co-normal term ``g -= tt Nco``; the "ring" variant on patch +
        ring, with the outer objective weighted 0 on the ring and Y fixed on the ring's outer nodes.
    anisotropy : str, callable or Anisotropy, optional
        Anisotropy gamma of the fully nonlinear anisotropic inner energy (closed meshes, or the "ring"
        boundary variant).
    tangential_weight : float
        beta >= 1 of the distance term (:class:`~willmore_nlp.model.terms.distance.Distance`).
    tangential_control : TangentialControl, optional
        Tangential motion inside the step (:mod:`willmore_nlp.tangential`); None: none.
    c0 : float
        Spontaneous curvature (:class:`~willmore_nlp.model.terms.helfrich.Helfrich`); 0: no term.
    volume, area : float, optional
        Targets of the outer constraints V[X] = volume, A[X] = area (closed meshes); None: free.
    extra_terms : sequence of Term
        Terms of the user's own (docs/guide/terms.md, "A term of your own"), added to the built-in ones.
    """
    control = TangentialControl() if tangential_control is None else tangential_control
    an = None if anisotropy is None else get_anisotropy(anisotropy, mesh.m)
    terms: list[Term] = [Distance(tangential_weight), AreaEnergy()]
    if not isinstance(control, TangentialControl) or control.enabled:
        terms.append(TangentialControlTerm(control, mesh.m))
    terms += [Willmore(), IsotropicInner() if an is None else AnisotropicInner(an)]
    if c0 != 0.0:
        terms.append(Helfrich(c0))
    if volume is not None:
        terms.append(VolumeConstraint(volume))
    if area is not None:
        terms.append(AreaConstraint(area))
    terms += list(extra_terms)
    if boundary is None:
        if not mesh.is_closed:
            raise MeshError(
                f"{mesh.source}: the mesh has a boundary ({len(mesh.boundary_facets)} boundary "
                "facets) but closed-surface flow needs a closed mesh; pass boundary=Boundary.outer_strip(mesh) "
                "(or another Boundary) for a clamped flow")
        for t in terms:
            t.check(mesh, None)
        return StepSetup(StepProblem(mesh.simplices, mesh.n_vertices, mesh.m, terms, name=_name(mesh, terms)),
                         anisotropy=an)
    if not isinstance(boundary, Boundary):
        raise TypeError(f"boundary must be a willmore_nlp.boundary.Boundary, got {type(boundary).__name__}")
    bd = boundary_data(mesh, boundary)
    for t in terms:
        t.check(mesh, bd.variant)
    # the inner problem lives on patch + ring: X is unknown on the free vertices, Y on the patch nodes
    # (free vertices and Gamma) and equal to X on the ring's outer nodes (docs/theory/scheme.md)
    cells = np.flatnonzero(bd.patch | bd.ring)
    patch = bd.patch[cells].astype(float)
    consts = {"patch": patch, "stiff": patch if bd.variant == "conormal" else np.ones_like(patch)}
    if bd.variant == "conormal":
        terms.append(Conormal(bd.nco))
    problem = StepProblem(mesh.simplices[cells], mesh.n_vertices, mesh.m, terms, x_free=bd.free,
                          y_free=bd.patch_nodes, element_const=consts, name="clamped_" + _name(mesh, terms))
    return StepSetup(problem, bd, anisotropy=an, simplices=mesh.simplices)


def _name(mesh: Mesh, terms: list[Term]) -> str:
    """Problem name: the terms' names and the dimensions."""
    return "_".join([*(t.name for t in terms if t.name), f"d{mesh.d}", f"m{mesh.m}"])
