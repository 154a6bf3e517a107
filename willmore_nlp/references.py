"""Reference values a run can be compared with: the smooth value and the mesh-matched one.

The *smooth* reference is the Willmore energy (or radius) of the exact target shape: 8 pi for a
sphere, 4 pi^2 for the Clifford torus, k pi / R for a k-fold circle of radius R, the radius
1/sqrt(2 lam) of a stationary circle with length energy lam. The *mesh-matched* reference is the
discrete Willmore energy (:func:`willmore_nlp.geometry.willmore_energy`) of that exact shape sampled
at the run's own resolution: the run's own connectivity with every vertex moved onto the target
shape. A 642-vertex icosphere scores 25.02, not 8 pi = 25.13; a 48 x 24 Clifford torus 39.02, not
4 pi^2 = 39.48. A converged run should approach the mesh-matched value; the gap to the smooth value
is discretisation bias, not an error.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from willmore_nlp.analysis import polygon_equilibrium_radius
from willmore_nlp.geometry import willmore_energy
from willmore_nlp.mesh import Mesh
from willmore_nlp.mesh.topology import euler_characteristic
from willmore_nlp.mesh.validate import face_normals


@dataclass(frozen=True)
class Reference:
    """A reference line for one history quantity.

    Attributes
    ----------
    column : the quantity: ``"willmore_energy"``, ``"willmore_gamma"`` (an anisotropic flow's) or ``"radius"`` (mean
        distance to the centroid)
    label : what the smooth value is, e.g. ``"8 pi (round sphere)"``
    smooth : the smooth value, a number or one value per state ((n_states,) array)
    matched : the mesh-matched value (same shape as ``smooth``), or None when there is none
    matched_label : how the mesh-matched value was obtained
    """

    column: str
    label: str
    smooth: float | np.ndarray
    matched: float | np.ndarray | None = None
    matched_label: str = ""


def _components(mesh: Mesh) -> int:
    S = mesh.simplices
    rows = np.repeat(S[:, 0], S.shape[1] - 1)
    cols = S[:, 1:].ravel()
    A = sp.coo_matrix((np.ones(rows.size), (rows, cols)), shape=(mesh.n_vertices,) * 2)
    return int(connected_components(A, directed=False)[0])


def segment_winding(V: np.ndarray, S: np.ndarray) -> float:
    """Winding number of a closed polygon around its vertex mean, from its segments (any vertex order).

    Parameters
    ----------
    V : (N, m) vertices (the x1-x2 projection is used)
    S : (N, 2) segments, oriented along the curve
    """
    c = V[:, :2] - V[:, :2].mean(axis=0)
    z = c[:, 0] + 1j * c[:, 1]
    return float(np.angle(z[S[:, 1]] / z[S[:, 0]]).sum() / (2 * np.pi))


def circle_nodes(V: np.ndarray, S: np.ndarray, k: int, radius: float) -> np.ndarray:
    """The run's curve moved onto a k-fold circle: vertex j at angle 2 pi k (j-th along the curve) / N.

    Parameters
    ----------
    V : (N, m) vertices of a single closed curve (only its connectivity is used)
    S : (N, 2) oriented segments
    k : covering number
    radius : circle radius

    Returns
    -------
    (N, m) vertices of a regular k-fold N-gon in the x1-x2 plane, in the order of the curve.
    """
    n = V.shape[0]
    nxt = np.empty(n, dtype=np.int64)
    nxt[S[:, 0]] = S[:, 1]
    pos = np.empty(n, dtype=np.int64)
    v = 0
    for j in range(n):
        pos[v] = j
        v = nxt[v]
    ang = 2 * np.pi * k * pos / n
    out = np.zeros_like(V, dtype=float)
    out[:, 0], out[:, 1] = radius * np.cos(ang), radius * np.sin(ang)
    return out


def sphere_nodes(V: np.ndarray) -> np.ndarray:
    """(N, 3) vertices projected radially onto the unit sphere around their mean."""
    c = V - V.mean(axis=0)
    return c / np.linalg.norm(c, axis=1, keepdims=True)


def clifford_nodes(V: np.ndarray) -> np.ndarray:
    """(N, 3) vertices of a torus-like surface moved onto the Clifford torus, in the frame of the torus of
    revolution nearest to them (:func:`~willmore_nlp.analysis.torus_frame`: free centre and axis).

    Each vertex keeps its two angles there: phi around the fitted axis and theta around the fitted core circle; the
    Clifford torus has radii sqrt 2 and 1. (The angles were taken about x3 through the vertex mean, around a core of
    radius the mean of the largest and smallest distance to that axis: a new user's torus, tilted 2.4 degrees and
    moved 0.14 after 80 steps, was given 39.587 where its own frame gives 38.978, and its flow's W 2.05 % below it
    instead of 0.52 %.)
    """
    from willmore_nlp.analysis import torus_frame

    _, centre, axis, core, _, _ = torus_frame(V)
    q = np.asarray(V, float) - centre
    height = q @ axis
    radial = q - np.outer(height, axis)  # (from the axis, its length rho; phi is its direction)
    rho = np.linalg.norm(radial, axis=1)
    theta = np.arctan2(height, rho - core)
    ring = np.sqrt(2.0) + np.cos(theta)
    # (in V's own frame: references' folding check compares each triangle's orientation with V's)
    return centre + (ring / rho)[:, None] * radial + np.outer(np.sin(theta), axis)


RESOLUTION_GAP = 0.03
"""A run warns when its last state's discrete Willmore energy lies more than this fraction below the least smooth
value of its topology (:func:`willmore_lower_bound`). The gap of an exact shape's mesh is O(h^2): the Clifford torus
on n x n/2 grids is 13.5 / 4.4 / 1.2 / 0.30 % below 4 pi^2 for n = 12 / 24 / 48 / 96 (orders 1.63, 1.90, 1.99;
tests/test_lower_bound.py), the 642-vertex icosphere 0.4 % below 8 pi; a 24 x 12 grid warns, a 48 x 24 one not."""


def willmore_lower_bound(mesh: Mesh) -> tuple[float, str] | None:
    """The least Willmore energy w = 1/2 int (k1 + k2)^2 of a smooth closed surface with the topology of ``mesh``.

    8 pi for every closed surface (Willmore 1965: int H^2 >= 4 pi, H = (k1 + k2)/2, equality for round spheres
    only) and 4 pi^2 for genus >= 1 (Marques and Neves 2014, the Willmore conjecture: int H^2 >= 2 pi^2, equality
    for the Clifford torus and its Moebius images). A discrete energy below it measures the discretisation error
    (the smooth flow cannot go there).

    Returns
    -------
    (bound, label), or None for curves, surfaces with boundary and meshes of several components
    """
    if mesh.d != 2 or mesh.m != 3 or not mesh.is_closed or _components(mesh) != 1:
        return None
    chi = euler_characteristic(mesh.simplices)
    if chi == 2:
        return 8 * np.pi, "8 pi, the least of any closed surface (Willmore)"
    return 4 * np.pi**2, f"4 pi^2, the least of any closed surface of genus {(2 - chi) // 2} (Marques-Neves)"


def resolution_warning(mesh: Mesh, willmore: float) -> str:
    """A one-line warning when ``willmore`` (the discrete Willmore energy of ``mesh``) lies more than
    :data:`RESOLUTION_GAP` below :func:`willmore_lower_bound`: the mesh does not resolve the shape to better than
    that gap; "" otherwise (or when there is no bound)."""
    bound = willmore_lower_bound(mesh)
    if bound is None or willmore >= (1 - RESOLUTION_GAP) * bound[0]:
        return ""
    return (f"the Willmore energy of the last state, {willmore:.5g}, is {100 * (1 - willmore / bound[0]):.1f} % below "
            f"{bound[1]}: on {mesh.n_vertices} vertices the discretisation error is at least that large; refine the "
            f"mesh (the file problem: --set remesh_target=H with H below the mean edge {mesh.h:.3g})")


def _outward(mesh: Mesh, V: np.ndarray) -> bool:
    """Whether every triangle of ``mesh`` with vertices ``V`` keeps the orientation it has in the mesh."""
    S = mesh.simplices
    return bool(np.all(np.einsum("ij,ij->i", face_normals(mesh.vertices, S), face_normals(V, S)) > 0))


def references(mesh: Mesh, lam: float, tau_tilde: float, times: np.ndarray,
               flow_options: dict[str, Any]) -> tuple[list[Reference], str]:
    """Reference lines for a run starting from ``mesh``.

    Parameters
    ----------
    mesh : the initial mesh
    lam : length/area energy weight
    tau_tilde : inner step (the discrete equilibrium radius of a k-fold polygon depends on it)
    times : (n_states,) times of the run's states (for the expanding circle)
    flow_options : the run's effective flow options (``boundary``, ``anisotropy``, both ``volume`` and ``area``, a
        nonzero ``c0``, and one of ``volume`` and ``area`` on a curve switch the isotropic references off)

    Returns
    -------
    refs : the references that apply (possibly none)
    note : why there is none, or which target was assumed
    """
    if "boundary" in flow_options:
        return [], "clamped boundary: no closed-form target shape"
    held = [k for k in ("volume", "area") if flow_options.get(k) is not None]
    anisotropy = str(flow_options.get("anisotropy", "gamma0"))
    if anisotropy != "gamma0":
        return _wulff(mesh, lam, anisotropy, held, float(flow_options.get("c0") or 0.0))
    if len(held) == 2:  # (a vesicle's report showed "Target: sphere", 8 pi and a gap of +19.6: a new-user check)
        if float(flow_options.get("c0") or 0.0) != 0.0:  # (a c0 = 0.5 vesicle's report named a Vesicle section it has
            # not: that section is for c0 = 0; a new user's check)
            return [], ("volume and area held fixed and spontaneous curvature c0: no closed-form or axisymmetric "
                        "reference (the Vesicle section's is for c0 = 0; docs/guide/vesicles.md)")
        return [], ("volume and area held fixed: the sphere is not reachable (a vesicle run's report has an "
                    "axisymmetric reference in its Vesicle section; docs/guide/vesicles.md)")
    if float(flow_options.get("c0") or 0.0) != 0.0:
        return [], "spontaneous curvature c0: no closed-form target shape"
    if not mesh.is_closed or _components(mesh) != 1:
        return [], "not a single closed curve or surface"
    V, S = mesh.vertices, mesh.simplices
    if held and mesh.d == 1:
        return [], (f"a curve with its {'enclosed area' if held == ['volume'] else 'length'} held fixed: not the "
                    "expanding circle; no closed-form reference used here")
    if mesh.d == 1:
        k = max(1, round(abs(segment_winding(V, S)))) if mesh.m == 2 else 1
        what = f"{k}-fold circle" if k > 1 else "circle"
        if lam > 0:
            R = 1 / np.sqrt(2 * lam)
            w = willmore_energy(mesh, vertices=circle_nodes(V, S, k, R))
            R_eq = polygon_equilibrium_radius(mesh.n_vertices, k, tau_tilde, lam)
            refs = [Reference("willmore_energy", f"k pi sqrt(2 lam) ({what} of radius 1/sqrt(2 lam))",
                              k * np.pi / R, w, f"regular {k}-fold {mesh.n_vertices}-gon of that radius"),
                    Reference("radius", "1/sqrt(2 lam)", R, R_eq,
                              f"equilibrium radius of the scheme for a regular {k}-fold {mesh.n_vertices}-gon")]
            return refs, f"stationary {what} of radius 1/sqrt(2 lam) = {R:.6g}"
        r = np.linalg.norm(V - V.mean(axis=0), axis=1)
        if np.ptp(r) > 1e-9 * r.mean() or k != 1 or mesh.m != 2:
            return [], "lam = 0 and the initial curve is not a circle: no closed-form solution"
        R = (r.mean() ** 4 + 2 * np.asarray(times, float)) ** 0.25
        w1 = willmore_energy(mesh, vertices=circle_nodes(V, S, 1, 1.0))
        return [Reference("willmore_energy", "pi / R(t), R(t) = (R0^4 + 2t)^(1/4)", np.pi / R, w1 / R,
                          f"regular {mesh.n_vertices}-gon of radius R(t)"),
                Reference("radius", "R(t) = (R0^4 + 2t)^(1/4)", R)], "expanding circle"
    chi = euler_characteristic(mesh.simplices)
    if chi == 2:
        target, smooth, label, what = sphere_nodes(V), 8 * np.pi, "8 pi (round sphere)", "sphere"
    elif chi == 0:
        target, smooth, label, what = clifford_nodes(V), 4 * np.pi**2, "4 pi^2 (Clifford torus)", "Clifford torus"
    else:
        return [], f"genus {(2 - chi) // 2}: no closed-form minimiser used here"
    if not _outward(mesh, target):
        return [Reference("willmore_energy", label, smooth)], f"the mesh does not map onto the {what} without folding"
    w = willmore_energy(mesh, vertices=target)
    # (one of V and A held: W is scale invariant, and the sphere or Clifford torus of that V or A is the target; a
    # new-user check, 2026-12-01: the report said "not reachable" while a 162-v ellipsoid with V held reached it)
    note = what + (f" ({held[0]} held fixed: W is scale invariant, the target is the {what} of that {held[0]})"
                   if held else "")
    return [Reference("willmore_energy", label, smooth, w, f"this mesh's vertices moved onto the {what}")], note


def _wulff(mesh: Mesh, lam: float, anisotropy: str, held: list[str], c0: float) -> tuple[list[Reference], str]:
    """The anisotropic flow's reference: w_gamma of the Wulff shape of gamma1, the least among closed surfaces in R^3
    (:func:`~willmore_nlp.anisotropy.gamma1_wulff_energy`, 42.9569), and the mesh-matched value, this mesh's vertices
    moved onto the Wulff shape along its gauge about their centroid (``reports/wulff_study.md``: the flow's rest on
    642 vertices within 0.07 % of it). A report of an anisotropic run had shown the isotropic W alone, which such a
    flow need not lower, and no reference (a new user's check)."""
    from willmore_nlp.anisotropy import (
        anisotropic_willmore_energy,
        gamma1_wulff_energy,
        gamma1_wulff_nodes,
        get_anisotropy,
    )

    if anisotropy != "gamma1" or mesh.d != 2 or mesh.m != 3:
        return [], (f"anisotropy {anisotropy}: no closed-form value here (the Wulff shape's is known for gamma1 on "
                    "closed surfaces in R^3)")
    if held or c0 or lam:
        return [], "anisotropy gamma1 with " + ", ".join([*held, *(["c0"] if c0 else []), *(["lam"] if lam else [])]) \
            + ": the Wulff shape is not the minimiser"
    if not mesh.is_closed or _components(mesh) != 1 or euler_characteristic(mesh.simplices) != 2:
        return [], "anisotropy gamma1: the Wulff shape is the reference of a single closed surface of genus 0 only"
    matched = anisotropic_willmore_energy(mesh.with_vertices(gamma1_wulff_nodes(mesh.vertices)),
                                          get_anisotropy("gamma1", 3))
    ref = Reference("willmore_gamma", "twice the area of the unit Wulff shape of gamma1 (its w_gamma at any size)",
                    gamma1_wulff_energy(), matched, "this mesh's vertices moved onto the Wulff shape")
    return [ref], ("the Wulff shape of gamma1, the ellipsoid x1^2 + x2^2 / 4 + x3^2 = R^2 (any R; w_gamma is scale "
                   "invariant)")
