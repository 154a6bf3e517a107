"""Clamped boundaries: restoration and blending (paper Secs. 2.2, 3.2, 5.2; Figs. 1, 8-10).

Every factory has a ``variant`` parameter, "conormal" (prescribed co-normal, paper (2.6)) or
"ring" (fixed outer ring, paper (2.8)); see :mod:`willmore_nlp.boundary`. The fixed parts of the
meshes carry one outer ring of simplices, from which the "conormal" variant takes its co-normal.
Defaults use tau_tilde = h^2 / 100: the "ring" variant collapses the first row of patch triangles
on curved surfaces for tau_tilde = h^2 / 10 (docs/guide/boundaries.md).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from willmore_nlp import geometry
from willmore_nlp.boundary import CLAMPED_CURVE_WEIGHT, Boundary
from willmore_nlp.mesh import shapes
from willmore_nlp.mesh.core import Mesh, MeshError
from willmore_nlp.registry import Problem, register


def _steps(h: float, tau: float | None, tau_tilde: float | None) -> tuple[float, float]:
    return (h if tau is None else float(tau)), (h * h / 100 if tau_tilde is None else float(tau_tilde))


def arc_mesh(n: int, R: float = 1.0, angle: float = 180.0) -> tuple[Mesh, np.ndarray, np.ndarray]:
    """Open polygon on the circle of radius R: ``n`` free nodes on an arc of ``angle`` degrees
    centred on +x1, one fixed boundary node and one fixed ring node at each end.

    Returns
    -------
    mesh : Mesh
    free : (n + 4,) bool
    theta : (n + 4,) polar angle of each vertex
    """
    shapes.vertex_count("arc", least=1, n=n)
    th = np.radians(angle) / 2 * np.linspace(-1, 1, n + 2)
    d = th[1] - th[0]
    th = np.concatenate([[th[0] - d], th, [th[-1] + d]])
    mesh = shapes.open_curve(R * np.stack([np.cos(th), np.sin(th)], axis=1), f"arc(n={n}, R={R}, angle={angle})")
    free = np.zeros(mesh.n_vertices, bool)
    free[2:-2] = True
    return mesh, free, th


@register("circle_arc")
def circle_arc(n: int = 64, R: float = 1.0, angle: float = 180.0, amp: float = 0.1, variant: str = "conormal",
               tau: float | None = None, tau_tilde: float | None = None, lam: float | None = None,
               steps: int = 100) -> Problem:
    """Curve segment on a circle of radius R, perturbed and restored with clamped ends (Fig. 1 left).

    The free nodes are displaced radially by ``amp * R * sin(3 pi s)`` (s in [0, 1] along the arc).
    lam = 1 / (2 R^2) (default) makes the circular arc an equilibrium: it is the length weight at
    which circles of radius R are stationary (kappa^2 / 2 = lam).

    The perturbation leaves Gamma at an angle (a kink of about 3 pi amp R / (angle h) radians against the clamped
    tangent), and with the ring variant IPOPT could not take the first step at some sizes: n = 128 and 144 failed
    every attempt from tau = h to h/16 (200 iterations each; a full step at iteration 8 left the constraint, the
    watchdog then sent the objective from 0.2 to 22), where n = 127 and 129 ran. So the problem's flows have
    ``fallback_solver = "newton-krylov"``, which takes that step at tau = h in 5 Newton iterations (the later steps
    are IPOPT's again; new-user check, 2026-11-30). ``tangential_weight`` = :data:`CLAMPED_CURVE_WEIGHT`: with the
    paper's 1 the 256-node ring arc's first free node slid onto Gamma and the run stopped at step 226-306.
    """
    mesh, free, th = arc_mesh(n, R, angle)
    s = (th - th[1]) / (th[-2] - th[1])
    V = np.array(mesh.vertices)
    V[free] *= (1 + amp * np.sin(3 * np.pi * s[free]))[:, None]
    tau_, tt_ = _steps(mesh.h, tau, tau_tilde)
    lam_ = 1 / (2 * R * R) if lam is None else float(lam)
    return Problem(mesh.with_vertices(V), tau_, tt_, lam_, steps=steps,
                   flow_options={"boundary": Boundary(free, variant), "fallback_solver": "newton-krylov",
                                 "tangential_weight": CLAMPED_CURVE_WEIGHT},
                   description="perturbed circular arc restored with clamped ends")


def cap_mesh(rings: int = 8, angle: float = 45.0) -> tuple[Mesh, np.ndarray, np.ndarray]:
    """Spherical cap (unit sphere) whose patch boundary Gamma is the latitude circle at ``angle``
    degrees with ``rings`` rings inside, plus one fixed outer ring.

    Returns
    -------
    mesh : Mesh (``rings + 1`` rings)
    free : (N,) bool, rings 0 .. rings - 1
    ring_index : (N,) int, ring of each vertex (``rings`` on Gamma)
    """
    if rings < 2:
        raise MeshError(f"sphere cap: rings must be >= 2, got {rings}")
    mesh = shapes.spherical_cap(rings + 1, angle * (rings + 1) / rings)
    th = np.arccos(np.clip(mesh.vertices[:, 2], -1, 1))
    k = np.rint(th / np.radians(angle / rings)).astype(int)
    return mesh, k < rings, k


@register("sphere_cap")
def sphere_cap(rings: int = 12, angle: float = 45.0, init: str = "bump", amp: float = 0.15, variant: str = "conormal",
               tau: float | None = None, tau_tilde: float | None = None, lam: float = 0.0, seed: int = 0,
               steps: int = 40) -> Problem:
    """Surface patch on the unit sphere, deformed and restored with clamped boundary (Fig. 1 right).

    ``init``: "bump" (radial bump ``1 + amp cos^2(pi theta / (2 theta_Gamma))``), "flat" (the
    patch pressed toward the plane of Gamma by the factor ``1 - amp`` in x3) or "noisy" (radial
    noise of relative size ``amp`` times h, seeded). The paper used tau = h = 0.02; the default
    here is 12 rings (h ~ 0.065), tau = h, tau_tilde = h^2 / 100.
    """
    mesh, free, _ = cap_mesh(rings, angle)
    V = np.array(mesh.vertices)
    th = np.arccos(np.clip(V[:, 2], -1, 1))
    thG = np.radians(angle)
    if init == "bump":
        V[free] *= (1 + amp * np.cos(np.pi / 2 * th[free] / thG) ** 2)[:, None]
    elif init == "flat":
        zG = np.cos(thG)
        V[free, 2] = zG + (1 - amp) * (V[free, 2] - zG)
    elif init == "noisy":
        rng = np.random.default_rng(seed)
        V[free] *= (1 + amp * mesh.h * rng.standard_normal(int(free.sum())))[:, None]
    else:
        raise MeshError(f"sphere_cap: init must be 'bump', 'flat' or 'noisy', got {init!r}")
    tau_, tt_ = _steps(mesh.h, tau, tau_tilde)
    return Problem(mesh.with_vertices(V), tau_, tt_, lam, steps=steps,
                   flow_options={"boundary": Boundary(free, variant)},
                   description="deformed spherical cap restored inside the unit sphere")


@register("curve_blending")
def curve_blending(n: int = 60, gap: float = 2.0, offset: float = 0.8, angle: float = 30.0, lam: float = 1.0,
                   variant: str = "conormal", tau: float | None = None, tau_tilde: float | None = None,
                   steps: int = 150) -> Problem:
    """Blend two straight segments with a curve of small Willmore + lam * length energy (Fig. 8).

    Left segment along +x1 ending at (-gap/2, 0); right segment ending at (gap/2, offset) and
    leaving in the direction ``angle`` degrees above +x1. The free curve starts as the straight
    line between them. The paper used tau = h = 0.01386, tau_tilde = 1.386e-5, lam = 1.
    """
    shapes.vertex_count("curve_blending", least=1, n=n)
    a = np.array([-gap / 2, 0.0])
    b = np.array([gap / 2, offset])
    L = float(np.linalg.norm(b - a))
    hh = L / (n + 1)
    left = a + np.outer(np.arange(-6, 0), [hh, 0.0])
    mid = a + np.outer(np.linspace(0, 1, n + 2), b - a)
    u = np.array([np.cos(np.radians(angle)), np.sin(np.radians(angle))])
    right = b + np.outer(np.arange(1, 7), hh * u)
    mesh = shapes.open_curve(np.concatenate([left, mid, right]), f"curve_blending(n={n})")
    free = np.zeros(mesh.n_vertices, bool)
    free[7 : 7 + n] = True
    tau_, tt_ = _steps(mesh.h, tau, tau_tilde)
    return Problem(mesh, tau_, tt_, lam, steps=steps, flow_options={"boundary": Boundary(free, variant)},
                   description="blending curve between two straight segments")


@register("surface_blending")
def surface_blending(r_bottom: float = 1.0, r_top: float = 0.8, gap: float = 1.2, n_around: int = 32,
                     n_gap: int = 10, lam: float = 0.0, variant: str = "conormal", tau: float | None = None,
                     tau_tilde: float | None = None, steps: int = 15) -> Problem:
    """Blend two coaxial cylinders of radii r_bottom and r_top across a gap (Fig. 9).

    Three fixed rows on each cylinder (Gamma, ring and one more); the ``n_gap - 1`` free rows start
    on the cone between the cylinders' ends and flow to a smooth blending surface. Measured with the
    paper's scheme (``mesh_control=off``): the default runs its 15 steps (energy settles by step 10);
    longer runs drift tangentially until the mesh check stops them (step 18), and r_top = 0.6 over gap 1
    collapses triangles by step 10. With the library defaults (mesh control on) and the paper's tangential
    weight 1, kept here, both variants come to rest: the relative change of W per step stays below 1e-8
    from step 256 (conormal) and 302 (ring) of 400, no retry, 3.1 IPOPT iterations per step; a weight of
    100 leaves 7.8e-7 per step after 400 steps
    (docs/guide/mesh_quality_measurements.md, "Restorations and blends at rest").
    """
    if n_gap < 2:
        raise MeshError(f"surface_blending: n_gap must be >= 2 (n_gap - 1 free rows), got {n_gap}")
    n_fixed = 3
    nz = 2 * n_fixed + n_gap
    dz = gap / n_gap
    mesh = shapes.cylinder(1.0, nz * dz, n_around, nz, z0=-(n_fixed * dz + gap / 2))
    V = np.array(mesh.vertices)
    row = np.rint((V[:, 2] - V[:, 2].min()) / dz).astype(int)
    s = np.clip((row - n_fixed) / n_gap, 0, 1)
    r = r_bottom + (r_top - r_bottom) * s
    V[:, :2] *= r[:, None]
    free = (row > n_fixed) & (row < n_fixed + n_gap)
    mesh = mesh.with_vertices(V)
    tau_, tt_ = _steps(mesh.h, tau, tau_tilde)
    return Problem(mesh, tau_, tt_, lam, steps=steps, flow_options={"boundary": Boundary(free, variant)},
                   description="blending surface between two cylinders")


def _refill(name: str, mesh: Mesh, free: np.ndarray, fill: str, amp: float, seed: int,
            normals: Callable[[], np.ndarray], axis: int, centre: Callable[[np.ndarray], float]) -> Mesh:
    """The restorations' coarse fill of the cut-out patch (``free``, (N,) bool): "noisy" moves each free vertex
    along ``normals()`` ((N, 3) unit normals of the uncut surface) by ``amp`` h times a seeded standard normal
    draw; "flat" presses the patch toward the plane x_axis = centre(x_axis of the patch) by the factor 1 - amp.
    """
    if not free.any():
        raise MeshError(f"{name}: the hole cuts out no vertex (hole = the radius of the cut-out ball)")
    if seed < 0:
        raise MeshError(f"{name}: seed must be an integer >= 0, got {seed}")
    V = np.array(mesh.vertices)
    if fill == "noisy":
        noise = np.random.default_rng(seed).standard_normal(int(free.sum()))
        V[free] += amp * mesh.h * noise[:, None] * normals()[free]
    elif fill == "flat":
        c = centre(V[free, axis])
        V[free, axis] = c + (1 - amp) * (V[free, axis] - c)
    else:
        raise MeshError(f"{name}: fill must be 'flat' or 'noisy', got {fill!r}")
    return mesh.with_vertices(V)


@register("torus_hole")
def torus_hole(n_major: int = 32, n_minor: int = 16, hole: float = 0.55, fill: str = "flat", amp: float = 0.3,
               variant: str = "ring", seed: int = 0, tangential_weight: float = 10.0, tau: float | None = None,
               tau_tilde: float | None = None, steps: int = 40) -> Problem:
    """Restoration (Fig. 10): a region of a torus (R = 1, r = 0.5) is cut out, filled with a coarse
    patch and restored by the flow with the rest of the torus fixed.

    The hole is the ball of radius ``hole`` around the outer equator point (1.5, 0, 0). ``fill``:
    "flat" (the patch pressed toward the plane x1 = const of its boundary by the factor 1 - amp)
    or "noisy" (normal noise of relative size ``amp`` times h, seeded). The paper used variant 2
    ("ring") for this figure.

    ``tangential_weight`` (default 10; 1 is the paper's scheme) charges the tangential part of the step's
    distance term that many times (the normal motion, and so the flow as h -> 0, is unchanged). Measured
    (100 steps, library defaults; docs/guide/mesh_quality_measurements.md, "Restorations and blends at rest"): with 1
    the step at tau = h slides the 15 free vertices toward degenerate triangles (budget cut or edge ratio
    3e3; accepted at h/2 or h/4, 4-7 deg before the repair), the light repair slides them back, and the
    accepted step size alternating between h/2 and h/4 leaves a 2-cycle (noisy fill: relative change of W
    1.5e-3 per step, 153 retries; flat: 6.8e-3, 260 retries); with 10 every step is taken at tau = h
    (no retry, 5 IPOPT iterations), W changes by less than 1e-8 per step from step 44 (noisy) and 43 (flat),
    the min angle stays 25.3 deg or more.
    """
    mesh = shapes.torus(1.0, 0.5, n_major, n_minor)
    V = np.array(mesh.vertices)
    free = np.linalg.norm(V - np.array([1.5, 0.0, 0.0]), axis=1) < hole

    def tube_normals() -> np.ndarray:  # the exact torus's unit normals (from the tube's core circle)
        nrm = V - np.column_stack([V[:, :2] / np.linalg.norm(V[:, :2], axis=1, keepdims=True), np.zeros(len(V))])
        return nrm / np.linalg.norm(nrm, axis=1, keepdims=True)

    mesh = _refill("torus_hole", mesh, free, fill, amp, seed, tube_normals, axis=0, centre=np.min)
    tau_, tt_ = _steps(mesh.h, tau, tau_tilde)
    return Problem(mesh, tau_, tt_, 0.0, steps=steps,
                   flow_options={"boundary": Boundary(free, variant), "tangential_weight": float(tangential_weight)},
                   description="torus with a cut-out region restored")


@register("genus2_blending")
def genus2_blending(h: float = 0.2, hole: float = 0.6, fill: str = "noisy", amp: float = 0.3, variant: str = "ring",
                    seed: int = 0, tangential_weight: float = 100.0, tau: float | None = None,
                    tau_tilde: float | None = None, steps: int = 200) -> Problem:
    """Higher-genus blending and restoration (Fig. 10): the junction of the two handles of a genus-2
    surface is cut out, refilled coarsely and restored by the flow with the rest of the surface fixed.

    The surface is :func:`~willmore_nlp.mesh.shapes.double_torus` (two tori R = 1, r = 0.5 centred at
    (+-1.25, 0, 0), smoothly joined) with mean edge ``h``; the patch is every vertex within ``hole`` of
    the saddle point where the two tori meet on the +x2 axis (a region of negative Gauss curvature that
    blends the two handles). ``fill``: "noisy" (normal noise of relative size ``amp`` times h, seeded) or
    "flat" (the patch pressed toward its mean plane x2 = const by the factor 1 - amp, which flattens
    the saddle and puts a kink at its boundary). The paper used variant 2 ("ring") for this figure.

    ``tangential_weight`` (default 100; 1 is the paper's scheme) charges the tangential part of the step's
    distance term that many times (the normal motion, and so the flow as h -> 0, is unchanged). Measured on
    the noisy default (40 free vertices, adaptive steps): with 1 the attempts at larger steps fail, tau stays
    at h/32-h/16 and the patch energy jumps by up to 1.9 % per step over 15 steps (between 2.563 and 2.644);
    with 100 the steps converge at tau = h in 5-6 iterations and the relative energy change falls below 1e-8
    at step 51 (reports/REPRODUCTION.md, Fig. 10; docs/guide/mesh_quality_measurements.md, "Genus 2").
    """
    from scipy.optimize import brentq

    mesh = shapes.double_torus(h=h)
    y0 = brentq(lambda y: float(shapes.double_torus_function(np.array([[0.0, y, 0.0]]))[0]), 0.0, 2.0, xtol=1e-12)
    free = np.linalg.norm(mesh.vertices - np.array([0.0, y0, 0.0]), axis=1) < hole
    mesh = _refill("genus2_blending", mesh, free, fill, amp, seed, lambda: geometry.vertex_normals(mesh), axis=1,
                   centre=np.mean)
    tau_, tt_ = _steps(mesh.h, tau, tau_tilde)
    return Problem(mesh, tau_, tt_, 0.0, steps=steps,
                   flow_options={"boundary": Boundary(free, variant), "tangential_weight": float(tangential_weight)},
                   description="genus-2 surface with its handle junction cut out and restored")
