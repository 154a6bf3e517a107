"""A flow of a user's mesh file (OBJ, PLY, OFF, STL, npz or a curve text file)."""

from __future__ import annotations

import math
import warnings

import numpy as np

from willmore_nlp.boundary import CLAMPED_CURVE_WEIGHT, VARIANTS, Boundary
from willmore_nlp.flow import REPAIR_PASSES_HANDLES, check_scale, ipopt_scale_trouble
from willmore_nlp.geometry import enclosed_volume, inward, length_scale
from willmore_nlp.mesh.core import Mesh
from willmore_nlp.mesh.io import load_mesh
from willmore_nlp.mesh.topology import components, euler_characteristic
from willmore_nlp.mesh.validate import simplex_volumes
from willmore_nlp.registry import Problem, ProblemError, register
from willmore_nlp.remesh import equilateral_edge
from willmore_nlp.settings import FlowSettings

FIRST_STEP_BUDGET = FlowSettings().iteration_budget_min
"""IPOPT iterations of a surface's first-step attempt before it is cut and retried at tau/2: ``iteration_budget_min``
(30), the floor of every later step's budget (the flow's own first-step default is 100). With ``adaptive`` steps an
attempt cut early costs little: the step continues from the step size that worked and grows back. The vesicle
problem's cup start uses it too (problems/vesicle.py)."""

NEWTON_KRYLOV_FROM = 500
"""Surfaces of at least this many vertices flow with ``solver = "newton-krylov"`` and ``fallback_solver = "ipopt"``
(a step newton-krylov fails at every tau is taken over by IPOPT); smaller ones with IPOPT and ``large_solver =
"newton-krylov"`` from this size, so the steps after ``input_repair`` refined a coarse input, or after a refinement
(``refine_dihedral``) grew the mesh, are newton-krylov's.
Measured, 20 steps each (docs/guide/performance.md, "The default for large files"): 12 users' surfaces of 550-2,562
vertices, 10 closed and 2 clamped, in 1.5-11.7x less time than IPOPT (7.3x on a 2,562-vertex ellipsoid), no step left to
the fallback; newton-krylov's first steps are sometimes taken at a smaller tau than IPOPT's. At 10,000-17,000 vertices:
a smooth ellipsoid's 10 steps in 166 s instead of 1,288 s; a noisy torus whose first step newton-krylov fails at every
tau is taken by IPOPT. The 128-vertex washer refined as a coarse torus (:data:`COARSE_TUBE`, 1,938 v): 40 steps in 186 s
instead of IPOPT's 406 s, the same final state to 0.04 % in W (both beside other runs)."""


COARSE_SIZE = 3.0
"""A closed surface of genus 0 whose size R = sqrt(area / 4 pi) is below this many edges h (of equilateral triangles
with its area and triangle count, :func:`~willmore_nlp.remesh.equilateral_edge`; R / h = sqrt(sqrt 3 n / 16 pi) for n
triangles, so fewer than 262 triangles) is refined before the first step (``remesh_target = R /``
:data:`COARSE_TARGET`, about 200 vertices on a sphere). The scheme shrinks a sphere at rate dR/dt = -16 tau_tilde /
R^5 (docs/theory/pitfalls.md), with tau_tilde = h^2 / 100 in a time t ~ R^6 / h^2, and the coarse mesh's own
discretisation adds to it. Measured, `willmore-nlp run X.obj --steps 30-40` on trimesh's raw primitives (R / h): the
icosahedron (12 v, 0.83) shrank to a point (mean edge 4e-6 at t = 20) and ended "completed"; the box (8 v, 0.64),
icosphere(1) and the subdivided icosahedron (42 v, 1.7), the cylinder (66 v, 2.1) and the box subdivided twice (98 v,
2.6) shrank until a step failed at t = 0.04-2.3; refined toward R / 4 (195-218 v) each ran 40 steps at tau = h with
0-1 retries to W = 24.72-24.77 (the round sphere at that resolution). The 162-vertex icosphere(2) (R / h = 3.3), the
cylinder subdivided once (258 v, 4.2) and every genus-0 input of the docs' tables are above the threshold. Not for
genus >= 1, where R is not the size that matters (a tube's radius is, :data:`COARSE_TUBE`): the 128-vertex trimesh
washer (R / h = 2.99) refined this way (185 v) ended 20 steps 3.4 % below 4 pi^2 instead of 1.4 % as given."""

COARSE_TARGET = 4.0
"""A coarse closed surface of genus 0 (:data:`COARSE_SIZE`) is remeshed toward the mean edge R / COARSE_TARGET."""

COARSE_TUBE = 1.5
"""A closed surface of genus >= 1 whose tube radius r = 2 V / A (exact for a torus of revolution with a round
section: V = 2 pi^2 R r^2, A = 4 pi^2 R r) is below this many edges h is refined before the first step
(``remesh_target = r /`` :data:`COARSE_TUBE_TARGET`). Its nodes drift until a fold stops the run: measured,
`willmore-nlp run X.obj --steps 40` (r / h): the 18 x 9 grid torus R = 1, r = 0.5 (162 v, 1.3) failed at step 9 (t =
1.33, W 34.1, the smallest angle 26.8 -> 5.3 deg in step 1); refined to 891 v it ran 40 steps, 10 retries, no failed
step, >= 25.4 deg, R/r 1.410, W 0.56 % below its mesh-matched Clifford torus. trimesh's 16 x 8 torus (128 v, 1.1) and
washer (128 v, 0.8) ran as given only through ``refine_dihedral`` (382 / 402 v, R/r 1.444 / 1.437); refined (897 /
1,938 v) R/r 1.424 / 1.419, 0.88 / 0.41 % below the reference, in 126 / 406 s instead of 29 / 29 s. The 24 x 12 grid
(1.7), trimesh's default torus (32 x 32 sections, 3.3), the level-set genus-2 surface (``shapes.genus2``, 1.9) and the
Lawson surface (4.3) are above the threshold; refined to r / 3 the 24 x 12 grid ran as well (924 v,
0.70 % below) but as given in 77 s instead of 133 s (542 v by refine_dihedral, 0.36 % below). These runs were
IPOPT's; the refined mesh's steps are now newton-krylov's (:data:`NEWTON_KRYLOV_FROM`): the 18 x 9 grid in 75 s, the
washer in 186 s. Times beside another run."""

COARSE_TUBE_TARGET = 3.0
"""A coarse closed surface of genus >= 1 (:data:`COARSE_TUBE`) is remeshed toward the mean edge r / this."""


@register("file", before={"length": 1.0})  # (tau = h in the file's units until 2026-11-29)
def from_file(path: str = "", tau: float | None = None, tau_tilde: float | None = None,
              lam: float = 0.0, steps: int = 10, clamp: str = "", length: float = 0.0) -> Problem:
    """A curve or surface from ``path`` (open ones: clamp=conormal|ring); tau = h L^3, tau_tilde = h^2/100.

    The step tau = h L^3 is the paper's tau = h in the mesh's own length L (``length``; 0, the default:
    :func:`~willmore_nlp.geometry.length_scale`, the radius of the sphere or disk of the surface's area, of the circle
    of a closed curve's length, half an open curve's length; per component), so that a mesh flows through the same
    shapes in any unit: Willmore flow takes X -> s X to t -> s^4 t, and tau = h would be s^3 times too large or small
    for a mesh written in other units (measured, 642-v ellipsoid 1:1:2, 20 steps: scaled by 100 it hardly moved, W 30.63
    -> 30.63 where the unit one became a sphere, 24.97; scaled by 0.01 its first step was taken at 6e-8 of its tau after
    2 retries; with tau = h L^3 the three flows agree step for step, W to 1e-9). ``length = 1`` is tau = h in the file's
    units, this problem's default before 2026-11-29 (night), at which the measurements quoted below were taken. A
    curve or surface farther from the origin than :data:`~willmore_nlp.flow.OFF_CENTRE` widths gets ``solver =
    "newton-krylov"`` alone (:func:`~willmore_nlp.flow.ipopt_scale_trouble`): IPOPT's absolute tolerances fail there
    (the 162-v ellipsoid moved 1e4 from the origin), newton-krylov's tolerance is relative (the same steps as at the
    origin, W to 1e-9). Its width does not: IPOPT solves a mesh narrower than 0.1 or wider than 1,000 in the unit
    of length in which it is 2 wide (:func:`~willmore_nlp.solvers.ipopt.length_unit`; until 2026-11-30 such meshes
    got newton-krylov too, as IPOPT's ``tol`` was met by steps that did not move, a 162-v ellipsoid 4e-5 wide, or
    failed, the same ellipsoid 28,000 wide).

    Surfaces get the surface defaults of the other surface problems: tau_tilde = h^2 / 100 (the
    scheme shrinks spheres at rate 16 tau_tilde / R^5, see docs/theory/tau_tilde.md) and the mesh control of
    :class:`~willmore_nlp.WillmoreFlow` (``remesh = "auto"``, the flow's default for surfaces; set
    ``remesh=off`` or ``mesh_control=off`` for the paper's scheme), and ``adaptive = true``: tau = h L^3 is
    the largest step, and a step that fails at it continues from the step size that worked (a trimesh
    torus of R/r = 2.5, weight 1, loses a quarter of its energy by t = 0.02; fixed tau = h then fails at step 2,
    whose retries stop at h/16), and ``max_retries = 8``: a raw input can need its first step far below h
    (a trimesh capsule, count 16 x 16, with noise of 1 % of its radius, 258 v, min angle 9.3 deg, flowed as given
    with ``input_repair = false``: every attempt from h to h/16 failed, the 100-iteration budget or a collapsed
    edge, and the run stopped after the default 4 retries; h/128 converges in 16 iterations and the adaptive steps
    are back at h by step 19; the default ``input_repair`` remeshes it before step 0, 241 v and 42.9 deg, and the
    first step is taken at h without a retry), and ``first_step_budget = 30`` (:data:`FIRST_STEP_BUDGET`; the
    failing first attempts of tori and creased inputs do not converge however long they run: step 1 of a 48x24 grid
    torus 117 -> 36 s, of the Lawson genus-2 surface 164 -> 48 s, the same trajectories; docs/guide/mesh_quality.md,
    "Noisy inputs: the first step"). A surface of at least :data:`NEWTON_KRYLOV_FROM` (500) vertices gets
    ``solver = "newton-krylov"`` with ``fallback_solver = "ipopt"``: 1.5-12x faster than IPOPT over 20 steps on
    the measured inputs; a smaller one gets IPOPT and ``large_solver = "newton-krylov"`` from that size (the steps
    on a mesh that ``input_repair`` or ``refine_dihedral`` made larger; ``--set solver=ipopt`` runs every step with
    IPOPT).
    Curves: tau_tilde = h^2 / 100 (as ``hypocycloid`` and ``hypocycloid3d``), and the surfaces' ``adaptive``,
    ``max_retries = 8`` and ``first_step_budget`` (before 2026-11-30 a fixed tau and the flow's 4 retries: at
    h^2 / 100 a noisy 150-point blob, radius noise 1 % of its size, failed its first step at every tau from h to
    h/16 with either solver; with these it takes it at h/128 and flows 200 steps to a circle, W L / 2 pi^2 =
    0.99979, the regular 150-gon's 0.99985). Until 2026-11-30 plane
    curves had h^2 / 4, at which a step can go to a spurious minimiser of the step problem: edges collapse and the
    polygon's Willmore energy jumps while the scheme's falls. Measured on plane ellipse files (aspect 1.5, 2 and 3,
    40-120 vertices, 10 steps each): 7 of 33 went wrong at h^2 / 4 (the 48-gon of aspect 3: edge ratio 808, W 4.4 ->
    169, exit 0; six others failed), none at h^2 / 10 or h^2 / 100; a closed space curve (60 vertices on x = 1.5
    cos t, y = sin t, z = 0.2 sin 3t) at h^2 / 4: edge ratio 327, W 4.9 -> 188.
    A curve's step that IPOPT fails at every tau is taken by newton-krylov (``fallback_solver``, whose stopping test is
    relative to the step's gradient): a smooth 400-vertex trefoil from a file failed its step 18 after five IPOPT
    attempts that ended "Solved_To_Acceptable_Level" (its accepted steps sat at KKT residuals of 1.5-5e-9 against
    IPOPT's absolute tol 1e-9); with the fallback and fixed tau it ran 40 steps, newton-krylov taking steps 18 and
    20-40 (with the adaptive steps IPOPT takes all 40 after 9 retries at smaller tau, t = 106 instead of 400).

    A closed surface oriented inward (or a closed plane curve running clockwise) is flowed with each simplex reversed,
    with a warning: the flow does not depend on the orientation, a volume constraint and c0 take the outward one.

    A mesh with a boundary needs ``clamp``: its outermost strip of simplices (every simplex with a
    vertex on the mesh boundary) is held fixed and clamps the rest, position and tangent plane
    (:meth:`~willmore_nlp.boundary.Boundary.outer_strip`), by the paper's prescribed co-normal
    (``clamp=conormal``) or fixed-ring (``clamp=ring``) variant. A clamped surface gets
    ``tangential_weight = 100`` (as ``genus2_blending``): with the paper's 1 the first free row slides
    toward the clamp (docs/guide/boundaries.md); a clamped curve gets
    :data:`~willmore_nlp.boundary.CLAMPED_CURVE_WEIGHT` (10), as ``circle_arc``.

    A closed surface of genus >= 1 (Euler characteristic <= 0) gets ``tangential_weight = 10``, the ``torus``
    problem's: with the paper's 1 its large first steps fight the scheme's tangential descent on tori (IPOPT under
    heavy regularisation, 200 iterations per attempt without converging). Measured, 20 steps each with this
    problem's other defaults: a 48x24 grid torus 8 retries and 160 s to t = 0.064 with weight 1, 5 retries and
    112 s to t = 0.23 with 10 (R/r 1.402 at t = 1.0); a noisy stretched trimesh torus 10 retries, 73 s, t = 0.11
    against 9, 72 s, t = 0.56; the 839-vertex double torus 12 retries, 122 s, t = 0.098 against 7, 73 s, t = 0.45
    (docs/guide/mesh_quality_measurements.md, "Which tangential_weight"). It also gets ``conformal_gauge = true``: over
    150 steps weight 10 alone let four tori slide along their Moebius orbit (R/r 0.6-1.39 instead of sqrt 2), with the
    gauge they end at R/r 1.420-1.425, t = 1.2-2.1, no failed step (mesh_quality_measurements.md, "To 150 steps"); a
    volume or area constraint turns the problem's gauge off (:meth:`~willmore_nlp.registry.Problem.effective_options`).
    ``--set tangential_weight=1 --set conformal_gauge=false`` is the paper's scheme. A closed surface of genus >= 1
    gets ``remesh_repair`` = :data:`~willmore_nlp.flow.REPAIR_PASSES_HANDLES` (4; the flow's default is 2).

    A closed surface of genus 0 smaller than :data:`COARSE_SIZE` (3) edges (its size sqrt(area / 4 pi); fewer than
    262 triangles) gets ``remesh_target`` a quarter of that size, with a warning: the scheme's shrinkage of order
    tau_tilde collapses or stops surfaces that coarse (trimesh's raw box, icosahedron, icosphere(1) and cylinder),
    and ``input_repair`` refines them to about 200 vertices before the first step (``--set remesh_target=H`` asks
    for another resolution, ``--set input_repair=false`` flows the input as given). A closed surface of genus >= 1
    whose tube radius 2 volume / area is below :data:`COARSE_TUBE` (1.5) edges gets ``remesh_target`` a third of it,
    with the same warning: the nodes of a tube that coarse drift until the mesh folds (an 18 x 9 grid torus failed at
    step 9; refined to 891 v it ran 40 steps without one).

    The surface step sizes this problem chooses (tau = h L^3, tau_tilde = h^2 / 100; not those given) are those of
    the mesh the flow runs on: when ``input_repair`` remeshes the input they follow its mean edge
    (``steps_from_h``; a 128-vertex washer repaired to 1,401 vertices with ``remesh_target = 0.08`` had run with
    tau = 4.8 h and tau_tilde = 0.23 h^2 of its own mesh, and its first step failed 7 times, 462 s).
    """
    if not path:
        raise ProblemError("problem 'file' needs path=... (a mesh file)")
    if clamp and clamp not in VARIANTS:
        raise ProblemError(f"problem 'file': clamp must be one of {', '.join(VARIANTS)} (or empty), got {clamp!r}")
    if not 0 <= length < math.inf:
        raise ProblemError(f"problem 'file': length must be a positive number (0: the mesh's own), got {length!r}")
    mesh = _outward(load_mesh(path), path)
    check_scale(mesh)  # (a mesh too wide is refused before L^3 can overflow; the flow warns)
    parts = components(mesh)[0]
    options: dict[str, object] = {"adaptive": True, "max_retries": 8, "first_step_budget": FIRST_STEP_BUDGET}
    chi = euler_characteristic(mesh.simplices) if mesh.d == 2 else None
    if clamp:
        options["boundary"] = Boundary.outer_strip(mesh, clamp)
        options["tangential_weight"] = 100.0 if mesh.d == 2 else CLAMPED_CURVE_WEIGHT
    elif not mesh.is_closed:
        raise ProblemError(f"the mesh has a boundary ({len(mesh.boundary_facets)} boundary facets): set "
                           "clamp=conormal or clamp=ring to hold its outermost strip of simplices fixed (volume "
                           "and area constraints need a closed surface)")
    elif chi is not None and chi <= 0:
        options.update(tangential_weight=10.0, conformal_gauge=True, remesh_repair=REPAIR_PASSES_HANDLES)
    if chi is not None and mesh.m == 3 and not clamp and parts == 1:  # (several: the flow's error)
        _refine_if_coarse(mesh, chi, options, path)
    if ipopt_scale_trouble(mesh.vertices):  # (IPOPT's absolute tolerances; newton-krylov's are relative: the same
        options.update(solver="newton-krylov")  # steps at any scale and place)
    elif mesh.d == 2 and mesh.n_vertices >= NEWTON_KRYLOV_FROM:
        options.update(solver="newton-krylov", fallback_solver="ipopt")
    elif mesh.d == 2:  # (from the refined input's first step, or a refinement's next step, on)
        options.update(large_solver="newton-krylov", large_vertices=NEWTON_KRYLOV_FROM)
    else:  # a curve: a step IPOPT fails at every tau is taken by newton-krylov (relative tolerance)
        options.update(fallback_solver="newton-krylov")
    if mesh.d == 2:  # tau = h and tau_tilde = h^2/100 of the mesh flowed, also when input_repair remeshes it
        chosen = [name for name, given in (("tau", tau), ("tau_tilde", tau_tilde)) if given is None]
        options["steps_from_h"] = "both" if len(chosen) == 2 else (chosen[0] if chosen else "none")
    h = mesh.h
    size = length or length_scale(float(simplex_volumes(mesh.vertices, mesh.simplices).sum()) / parts, mesh.d,
                                  mesh.is_closed)  # (per component; areas only: a sliver is an error later)
    return Problem(mesh, h * size**3 if tau is None else tau, 0.01 * h * h if tau_tilde is None else tau_tilde,
                   lam, steps=steps, flow_options=options, description=f"mesh from {path}")


def _outward(mesh: Mesh, path: str) -> Mesh:
    """``mesh`` oriented outward: a closed curve in the plane or closed surface in R^3 of one component whose signed
    enclosed volume is negative is given with each simplex reversed, with a warning. The Willmore flow does not depend
    on the orientation; a volume constraint and a spontaneous curvature c0 take the outward one (an inward ellipsoid
    file with ``volume = initial`` was refused with "volume must be a positive number", and with c0 = 1 it flowed
    as c0 = -1: found by a new-user check)."""
    if not (mesh.is_closed and mesh.m == mesh.d + 1) or components(mesh)[0] != 1:
        return mesh
    state = inward(mesh)
    if not state:
        return mesh
    warnings.warn(f"{path}: {state}: it is flowed with each {'triangle' if mesh.d == 2 else 'segment'} reversed, "
                  "outward, as volume constraints and the spontaneous curvature c0 take it", stacklevel=3)
    return Mesh(mesh.vertices, np.asarray(mesh.simplices)[:, ::-1], mesh.source)


def _refine_if_coarse(mesh: Mesh, chi: int, options: dict[str, object], path: str) -> None:
    """Set ``remesh_target`` (with a warning) when the closed surface ``mesh`` is coarse: genus 0 by its size
    sqrt(area / 4 pi) (:data:`COARSE_SIZE`), genus >= 1 by its tube radius 2 volume / area (:data:`COARSE_TUBE`)."""
    h = equilateral_edge(mesh.vertices, mesh.simplices)  # (areas only: a sliver is an error later)
    area = math.sqrt(3) / 4 * h * h * len(mesh.simplices)
    if chi == 2:
        size, limit, target = length_scale(area, 2, True), COARSE_SIZE, COARSE_TARGET
        what, why = "sqrt(area / 4 pi)", "the scheme's shrinkage of order tau_tilde collapses surfaces that coarse"
    else:
        size, limit, target = 2 * abs(enclosed_volume(mesh)) / area, COARSE_TUBE, COARSE_TUBE_TARGET
        what, why = "its tube radius 2 volume / area", "the nodes of tubes that coarse drift until the mesh folds"
    if size < limit * h:
        options["remesh_target"] = size / target
        warnings.warn(f"{path}: a closed surface of {mesh.n_vertices} vertices only {size / h:.2g} edges in size "
                      f"({what} = {size:.3g}): {why}, so remesh_target = {size / target:.3g} refines it "
                      "before the first step unless input_repair is false (--set remesh_target=H for another, --set "
                      "input_repair=false flows it as given)", stacklevel=3)
