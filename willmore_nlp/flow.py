"""The time loop: one NLP per step, warm starts, retries with smaller steps, energy checks."""

from __future__ import annotations

import dataclasses
import math
import textwrap
import time
import warnings
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from willmore_nlp import geometry
from willmore_nlp.anisotropy import Anisotropy, anisotropic_willmore_energy, get_anisotropy
from willmore_nlp.boundary import check_mask_size
from willmore_nlp.codegen import compile_kernels, find_compiler
from willmore_nlp.errors import UserInputError
from willmore_nlp.mesh import shapes
from willmore_nlp.mesh.core import Mesh, MeshError
from willmore_nlp.mesh.topology import edge_triangles
from willmore_nlp.model.build import build_step
from willmore_nlp.model.evaluator import StepEvaluator
from willmore_nlp.model.terms.base import Term
from willmore_nlp.model.terms.tangential_control import TangentialControlTerm
from willmore_nlp.settings import (
    SOLVER_ROLES,
    FlowSettings,
    check_run_value,
    flatten_ipopt,
    is_number,
    route_solver_options,
)
from willmore_nlp.solvers import check_solver, make_solver, solver_capabilities, solver_settings
from willmore_nlp.solvers.base import SolveResult
from willmore_nlp.solvers.ipopt import UNIT_WIDTHS, length_unit
from willmore_nlp.tangential import TangentialControl, default_weight, resolve_method


class FlowError(RuntimeError):
    """The flow cannot go on: a step failed after every allowed retry.

    Attributes
    ----------
    step : the step that failed
    t : time of the last accepted state
    rejected : reasons of the rejected attempts, ``"tau=...: reason"`` (``"tau=...: SOLVER: reason"`` with a
        ``fallback_solver``)
    results : the steps :meth:`WillmoreFlow.run` accepted before the failure (empty from :meth:`WillmoreFlow.step`)
    hint : what the message ends with after the rejected attempts: how to take the step ("" none)
    """

    def __init__(self, message: str, *, step: int = -1, t: float = float("nan"),
                 rejected: list[str] | None = None, hint: str = "") -> None:
        super().__init__(message + hint)
        self.step = step
        self.t = t
        self.rejected = list(rejected or [])
        self.hint = hint
        self.results: list[StepResult] = []


class StepInterrupted(Exception):  # noqa: N818 (an outcome, not an error)
    """A stop was requested (:attr:`WillmoreFlow.stop_requested`) while a step was under way.

    The step was abandoned without retrying it; the flow's state is that of the last accepted
    step, so continuing from it later gives exactly the results of an uninterrupted run.

    Attributes
    ----------
    step : the abandoned step
    """

    def __init__(self, step: int) -> None:
        super().__init__(f"step {step} abandoned on request")
        self.step = step


CONVEX_JUMP = 16
"""``convex_start``: the first step jumps below its convexity limit tau_c only when tau_c < tau / CONVEX_JUMP, i.e.
beyond the flow's default four halvings (the smooth 162-vertex ellipsoid 1:1:2 and 16x8 grid torus with tangential
weight 1 of the tests have tau_c = tau / 4.7 and tau / 6.8 and are taken by the halvings at tau / 2 - tau / 16, the
smooth files of docs/guide/mesh_quality.md tau / 2.9 - tau / 11.9 or none; its noisy inputs have tau / 750 -
tau / 6.3e6)."""

CONVEX_FAR = 1e5
"""``convex_start``: the first step starts below tau_c, before newton-krylov's first attempt (after another solver's
first failure), when a first look of two Lanczos cycles (:data:`~willmore_nlp.solvers.reduced.CONVEXITY_FIRST_RESTARTS`)
finds tau_c < tau / CONVEX_FAR: the attempts at tau and tau / 2 are then the same hopeless non-convex problem and were
most of a large noisy input's first step (400 of 441 s at 39,891 vertices). Measured: the largest tau / tau_c whose
attempt at tau / 2 converged is the smoothed box's 10,860 (a ninth of this); newton-krylov's attempt at tau converged
up to 3.4e4 (a noisy capsule of 445 v) and failed on each of 13 inputs above 1e5 (1.0e5-6.3e6, 1,613-40,962 v);
IPOPT took one of them at tau (a noisy icosphere of 2,279 v, 2.8e5), so it keeps its first attempt. The cone, the
cylinder and the noisy 10,192-vertex torus (tau / 3.0e4 - tau / 5.0e4) keep their attempts at tau and tau / 2."""

SKIP_REASON = "not tried: convex only below tau_c, under min_tau"
"""The reason recorded when newton-krylov's first-step attempts are left to the ``fallback_solver`` (:data:`CONVEX_FAR`:
the first look finds tau_c far below tau and below the step-size floor, so no attempt can start below it)."""

FLOOR_REASON = "step size below min_tau"
"""The reason recorded for an attempt that the step-size floor ``min_tau`` stopped (no solve)."""

FOLD_REASON = "mesh folds"
"""How the reason of an attempt refused by the fold check (``max_dihedral``) begins."""

EDGE_RATIO_REASON = "mesh quality: edge ratio"
"""How the reason of an attempt refused by the edge-ratio limit ``max_edge_ratio`` begins (the run's error line then
names ``redistribute`` for a closed curve: :func:`willmore_nlp.runner.spacing_hint`)."""

GROWN_FALL = 0.01
"""A grown step that lowers the step objective by less than this fraction may not take the mesh below
``remesh_min_angle`` (:meth:`WillmoreFlow._crushes`): on a genus-2 flow the threshold remeshings lifted W by 0.1-0.7 %,
the remeshing and refinement after one such step by 2.2 % (docs/guide/mesh_quality_measurements.md, "Grown steps")."""

GROWN_REASON = "grown step crushes the mesh"
"""How the reason of a grown attempt refused for the mesh's sake begins (:meth:`WillmoreFlow._crushes`)."""

COLLAPSE_FRACTION = 1 / 3
"""An attempt (not a solver's last) that takes the patch's smallest angle from at or above ``remesh_min_angle`` to below
this fraction of it is retried at tau / 2 (:meth:`WillmoreFlow._collapses`). Measured in first steps at the file
defaults (trimesh torus R/r 5, 48 x 12): the step at tau left 1.43-deg slivers with W 37.3 below the torus's 4 pi^2,
the remeshing lifted W to 54.8 and step 2 then needed 8 retries; the healthy inputs' steps (a capsule, a cone, a
cylinder, a box, ellipsoids, the genus-2 surfaces) stay above 18 deg."""

SOLVER_REASON = "solver did not converge"
"""How the reason of an attempt whose solver did not converge begins."""

COLLAPSE_REASON = "step collapses the mesh"
"""How the reason of an attempt refused by :meth:`WillmoreFlow._collapses` begins."""


def _never() -> bool:
    return False


def _ignore(text: str) -> None:
    return None


def _past(x: float, limit: float) -> str:
    """``x`` to 3 significant digits, or to as many as show it apart from the ``limit`` it is past (a rejection read
    "min angle 0.5 deg < 0.5": a new user's check)."""
    for digits in (3, 6, 17):
        text = f"{x:.{digits}g}"
        if float(text) != limit:
            break
    return text


class StepSizeWarning(UserWarning):
    """tau_tilde far above h^2: the step loses tangential convexity and nodes cluster (docs/theory/tau_tilde.md)."""


class LooseToleranceWarning(UserWarning):
    """A step solver accepted a step at its start, X unmoved, only because its ``tol`` is looser than its default."""


class InputRepairWarning(UserWarning):
    """``input_repair`` changed the input before the first step (a resume past that step does not repeat it)."""


MAX_MESH_SIZE = 1e5
"""WillmoreFlow refuses meshes wider than this: IPOPT's absolute tolerances fail there (measured:
an ellipse or ellipsoid scaled by 1e4 with tau ~ L^4 reproduces the unit-size steps to 3e-12,
scaled by 1e6 every step fails)."""

SMALL_MESH_SIZE, LARGE_MESH_SIZE = UNIT_WIDTHS
"""WillmoreFlow warns when ``sqp`` or a reduced solver (absolute tolerances) may run on a mesh narrower or wider than
these. IPOPT solves the steps of such a mesh in the unit of length in which it is 2 wide
(:func:`willmore_nlp.solvers.ipopt.length_unit`; before, measured: the unit-size steps were reproduced to 2e-7
(ellipse) and 2e-3 (ellipsoid) at scale 1e-2, and not at all, 0 iterations, at 1e-4; on 10 steps of the 162-v
ellipsoid 1:1:1.4 scaled to width w: w = 280 repeated the unit steps, W to 1e-9; w = 2,800 needed a retry and ended
1.5e-5 off, w = 28,000 6 retries and 2 % off, w = 84,000 failed); newton-krylov's tolerance is relative."""

OFF_CENTRE = 100.0
"""WillmoreFlow warns when IPOPT may run on a mesh whose farthest coordinate exceeds this many of its widths (and the
``file`` problem gives it newton-krylov). Measured (the same ellipsoid, 2.8 wide, moved by c along every axis, 10
steps): c = 100 repeats the centred steps (W to 1e-9); c = 1,000 needs a retry and falls behind (t = 2.47 against
4.79), c = 1e4 crawls and c >= 1e5 fails step 1; newton-krylov repeats them to c = 1e5 (found by a new-user check)."""

MAX_OFF_CENTRE = 1e4
"""WillmoreFlow refuses a mesh whose farthest coordinate exceeds this many of its widths: its coordinates then keep too
few digits of its shape (float64: about 16 digits in all). Measured (the ellipsoid of :data:`OFF_CENTRE`): newton-krylov
repeats the centred steps at c = 1e5 (3.6e4 widths) and fails step 1 at every tau at c = 1e6 (3.6e5 widths; its line
search stops at round-off of the coordinates, about 1e-16 of 1e6 against edges of 0.5). A finer mesh loses as many
digits a few times closer (edges h: the round-off relative to h is what counts), hence 1e4, a tenth of the last width
measured to work on a mesh of 162 vertices."""

BUDGET_WINDOW = 20
"""The iteration budget is a multiple of the median iteration count of this many last accepted steps."""

RELAX_WINDOW = 3
"""The relax test looks at the Willmore energy over this many last steps (:meth:`WillmoreFlow.step`)."""

DRIFT_SHARE = 0.5
"""A step whose normal motion lies this much (squared lumped L^2 norm) in the span of the ten conformal fields,
the Willmore energy's zero modes, is the scheme's drift rather than the flow's motion (the smooth flow's is
orthogonal to them): it counts as at rest (``rest_tau_tilde``) and its dilation is undone (``rest_dilation``).
Measured (docs/guide/mesh_quality.md): 0.001-0.11 in steps that round a trimesh box, cylinder or 1:1:2 ellipsoid,
0.31 and 0.78 as the ellipsoid's own motion dies out, 0.95-0.9999 at rest before tau_tilde is lowered."""

TARGET_CHANGE = 0.1
"""A ``remesh_target`` more than this fraction away from the input's equilateral edge remeshes the input before the
first step (``input_repair``), whatever its quality: refining (or coarsening) a mesh is asked that way, as the
end-of-run resolution warning advises (:func:`willmore_nlp.references.resolution_warning`)."""

INPUT_SHAPE_CHANGE = 0.3
"""``input_repair`` refuses a remeshing of the input that changes its area by more than this fraction (an error that
names the cause): measured, the repairs of a trimesh capsule and a noisy capsule change it by 0.9 % and 2.2 %, those
of coarse trimesh cones (34 and 98 vertices, new vertices on the input's triangles cut the apex and the rim) by 11 %
and 15 % and then flow (tests/test_remesh.py, test_convex_start.py), while the remeshings of a 1 x 1 x 0.02 box (386
v, triangles 0.1 wide on faces 0.02 thick) and a 1 x 1 x 0.001 one shrank them by 84 % and 100 % (to 89 and 4
vertices; a new-user check), as any remeshing at edges longer than the features."""

RESTORE_LIMIT = 0.25
"""A mesh repair is dropped when moving the repaired mesh back onto the volume/area targets would move a vertex
by more than this many mean edge lengths (a least-norm correction of a coarse remeshed vesicle built a spike)."""

RESTORE_HALVINGS = 3
"""Halvings of a light repair whose restoration onto the volume/area targets moves a vertex too far
(:meth:`WillmoreFlow._restored`)."""

CONSTRAINT_RTOL_SOLVER = 1e-6
"""Largest relative residual of an outer constraint (volume, area) that a solve may leave: the state is
then moved onto the constraints (:meth:`WillmoreFlow._restore`, to 1e-13); more rejects the step."""

SADDLE_TOL = 0.1
"""A relaxed state is a saddle (``relax_check``) when the lowest eigenvalue of :meth:`WillmoreFlow.stability`
(dimensionless) is below -SADDLE_TOL. Measured at 534-642 vertices: minima 4.3 (the c0 = 0.8 vesicle's prolate), 6.4
(the discocyte, v = 0.65), 16.9 (oblate v = 0.55), 22.3 (prolate v = 0.85), 24 (a round sphere, the closed form);
the c0 = 0.8 vesicle's plateau -1.14 and -0.45."""
SADDLE_KICK = 1.0
"""Largest nodal move of the step off a saddle (``relax_check``), in mean edge lengths h (the move is the best of 1,
1/2, 1/4, 1/8 of it): on the c0 = 0.8 vesicle (534 v) the three moves lowered the energy by 0.003 %, 0.037 % and
0.052 % (h / 8 - h / 4: along the mode the energy turns up within h / 2), enough to start the unstable mode, which the
flow then follows (left in 95 steps; without the moves it stayed above the saddle's energy for 140 steps)."""
MAX_SADDLE_KICKS = 3
"""Saddles a relaxation leaves (``relax_check``) before it ends on one."""
POLISH_GAP = 1e-12
"""The gap (relative) below which a relaxed minimum is not polished further (``relax_check``)."""
POLISH_MAX_GAP = 1e-2
"""The largest gap (relative) a relaxed minimum is polished from (``relax_check``): above it the state is not at rest
on normal motions (a 162-vertex c0 = 0.8 vesicle relaxed on the step/repair exchange with a gap of 9.2e-2; three
polishing steps at the h / 4 cap lowered e by 1.6 %, its smallest angle from 41 to 21 deg and its lowest eigenvalue
to -0.03: a new user's check). Measured at rest: 1.6e-3 and 2.9e-3 (trimesh tori), 1.4e-3 (Lawson's genus 2),
3e-4 (a vesicle), 1.2e-5 (a capsule)."""
MAX_GO_ON = 10
"""Times a relaxation goes on past its window's end (``relax_check``) when the check finds the state not at rest on
normal motions (a gap above :data:`POLISH_MAX_GAP`, not a saddle): the window's energies rose or stalled on the
step/repair exchange, not at rest. Measured (2026-12-02, a new user's check): the 162-vertex c0 = 0.8 vesicle with
time steps only (``relax_newton=false``) ended "relaxed" at step 7 at e = 29.347 with a gap of 9.2e-2, 26 % above its
minimum; going on, its time steps reach e = 23.2986 at step 27 (gap 5e-14), where the flow with Newton steps
(``relax_newton``, the default) ends at 23.3149 after 23 steps. Each end tested costs one
:meth:`WillmoreFlow.stability`."""
POLISH_STEPS = 4
"""Newton steps on normal motions of the polish of a relaxed minimum (each costs one :meth:`WillmoreFlow.stability`)."""
POLISH_CAP = 0.25
"""Longest nodal move of one polishing Newton step, in mean edge lengths h."""
STABILITY_MAX_VERTICES = 50000
"""Largest surface :meth:`WillmoreFlow.stability` takes. Up to
:data:`~willmore_nlp.solvers.reduced.SPECTRUM_DENSE_MAX` free nodes the Hessian on normal motions is dense (one
Hessian-vector product per node: 0.4 s at 534 vertices, 13 s at 2,562, 119 s at 5,000), above it iterative
(lobpcg and CG, matrix-free): measured at the ellipsoid 1:1:1.3 with ``newton-krylov``'s factorisations, 4.0 s at
10,242 vertices (8.6 s with IPOPT's flow, whose products use a sparse LU) and 33 s at 40,962 (0.8 GB peak); a
relaxation's check and each polishing step cost one."""
NEWTON_SOLVER = "normal-newton"
"""History ``solver`` of a relaxation's Newton step on normal motions (``relax_newton``)."""
RELAX_NEWTON_CAP = 2.0
"""Longest nodal move of a relaxation's Newton step on normal motions (``relax_newton``), in mean edge lengths h.
Measured on the ellipsoid 1:1:2 (reports/relax_study.py), steps to within 1 % of the equilibrium energy at 642 /
2,562 vertices: cap 0.5: 6 / 12; 1: 3 / 6; 1.5: 3 / 4; 2: 3 / 3 (2026-11-30, night; that evening, before the flow's Y[X]
solves of such a relaxation used the Cholesky factor, the 642-vertex one's first step at cap 2 left no Newton step);
4: the 2,562-vertex one's step lowered e by wrecking the mesh (W 25.5 -> 76.8, 5.6 deg; hence the repair thresholds'
test). Cap 2 against 1 on other inputs (file and vesicle defaults, ``relax``), final e: trimesh tori 64 x 24 (r 0.35)
39.613 / 39.593 and 72 x 28 (r 0.45) 39.555 / 39.586, capsule 25.1489 / 25.1477, vesicles v = 0.85 32.2298 /
32.2292, v = 0.65 46.147 / 46.168, v = 0.65 with c0 = 0.8 23.510 / 23.507; v = 0.75 ended at a minimum (37.638)
where cap 1 ended on a saddle (39.632, lowest eigenvalue -0.03). A trust region (the cap doubled after a capped step
taken whole, up to 2 or 4) took 4 steps at 2,562 but left a 1,513-vertex trimesh torus at a minimum on normal motions
0.45 % above the one of the fixed cap 1 (e 39.771 against 39.593; the time steps: 39.595)."""
REPAIR_SPEED = 1.0
"""Each pass of the light repair moves a vertex by at most this factor times the distance the step moved it."""

REPAIR_PASSES_HANDLES = 4
"""``remesh_repair`` that the ``torus`` and ``file`` problems give closed surfaces of genus >= 1 (the flow's
default: 2). The 48x24 torus to t = 1 with the conformal gauge (tau = 1e-3, 2026-11-29): the lowest W 0.31 % below
the grid's Clifford torus with 4 passes, 0.68 % with 2 (the issue's band: 0.5 %), no retry, smallest angle >= 15.5
deg stepped either way; a trimesh torus file (991 v): 0.28 % below its mesh on the fitted Clifford torus at t = 0.28
against 0.66 % (1.09 % by t = 0.44); near rest a genus-2 file ran 300 steps without a remeshing where 2 passes
were outrun by a vertex that every step slid 0.2 h. Against: an 800-v stretched noisy torus crept up at rest
(1.4e-6 per step, 40 of its last 50 steps against 21), and a deliberately coarse 72-v torus folded at step 3 (the
``file`` problem refines such tori first) (docs/guide/mesh_quality.md, "Tori and genus 2: four repair passes")."""

FLIP_RISE = 1e-4
"""Near rest (the option ``flip_rest``) and while the patch is above its thresholds the mesh control's Delaunay
flips are dropped when they would raise the lumped Willmore energy by more than this fraction (a moving surface, or a
patch below the thresholds, gets every flip). Near rest the nodes still slide slowly and edges cross the Delaunay
condition: 8 symmetric flips of edges at 180.5 degrees raised the lumped W of a 642-v ellipsoid 1:1:1.6 held at its
volume and area by 0.17 % (the scheme's energy by 0.27 %), which the next two steps took back
(docs/guide/mesh_quality.md, "Flips near rest")."""

REPAIR_ROUNDS = 5
"""The light repair (``remesh_repair``) repeats its passes up to this many times while the mesh is below the
repair thresholds, before the stronger repairs (projected smoothing, isotropic remeshing) are tried."""

NEW_VERTICES = frozenset({"remesh", "refine"})
"""Mesh-control actions (history ``remesh_action``, joined by "+") after which the vertices are new ones."""

REFINE_FACTOR = float(np.sqrt(2.0))
"""A refinement (``refine_dihedral``) remeshes toward the current edge divided by this (about twice the vertices)."""

LOCAL_REFINE_ANGLE = 0.6
"""The region of a local refinement (``refine_local``) starts at the vertices of the edges whose triangles' normals
turn by more than this fraction of ``refine_dihedral``."""

LOCAL_RINGS = 2
"""A local refinement's region, and that of a threshold remeshing of a locally refined mesh, grows by this many rings
of triangles around its start (the rim, which stays fixed, is then away from the edges it mends)."""

REST_SPEED = 3e-3
"""A clamped or open surface at rest on a healthy mesh keeps its mesh (:meth:`WillmoreFlow._pauses`): after a step that
moved no moving node along its vertex normal faster than this many L per unit of the surface's own time L^4 (L:
:func:`geometry.length_scale`), the light repair and the in-step tangential control pause. Each paused step is the
paper's step and stands if it moves no moving node, tangentially included, faster than this or than the step before
it (a slide that dies out: the scheme's own way to its discrete minimum); otherwise it is taken again with the control
and the controls stay on for the rest of the flow (the scheme's own tangential drift, which they exist to follow; a
rejected paused attempt is taken again with the control too, and ends that pause only).
Measured at tau = h (docs/guide/mesh_quality.md, "Clamped and open surfaces at rest"): the first step's normal motion
5e-7 (helicoid, 325 v) and 1.9e-3 (catenoid, 816 v, settling on its discrete minimum), 6e-5 and 1.3e-3 in later steps
with the controls; paused steps 2e-5 and 2e-4; the clamped hemisphere (``sphere_cap``, angle 90) and 45-degree cap
pause at 2.9e-3 and 3.6e-4 while their normal motion dies out, and their paper's step then moves the nodes at 0.1 and
3e-2, so the controls stay on from there. The slide that dies out (2026-12-03): a 566-vertex clamped Enneper patch's
paused steps move the nodes at 1.01e-2 after its controlled step's 1.05e-2, then 9.4e-3, 8.6e-3, ... (below this from
step 16): W 1.35e-4 at step 150 instead of 4.31e-4 (the paper's scheme: 1.39e-4); the 45-degree cap's and the
90-degree cap's (its bump start) first paused steps are faster than the controlled steps before them (1.92e-2 after
1.65e-2, 7.5e-2 after 6.5e-2); from its flat and noisy starts the 90-degree cap keeps the pause, and its smallest
angle ends at the paper's scheme's level, 5-11 deg below the controls'."""

CONTROL_OFF = TangentialControlTerm.scalars
"""``off`` of :meth:`WillmoreFlow.params` for the evaluations the tangential control does not enter (an outer term):
the inner solve, the outer constraints, the energy e(X); its per-node data are then not computed."""

TAU_TILDE_WARN_FACTOR = 2.0
"""WillmoreFlow warns (:class:`StepSizeWarning`) when tau_tilde > this factor times h^2 (h = mean edge)."""
TAU_TILDE_LOW_FACTOR = 1e-4
"""WillmoreFlow warns (:class:`StepSizeWarning`) when tau_tilde < this factor times h^2 and its steps are IPOPT's.
Measured (2026-12-03, two steps at tau = h, 4 retries): IPOPT failed the first or second step from 1e-5 h^2 down on a
162- and a 642-vertex ellipsoid and a 64-gon (at tau = h^4), and took them at 1e-4 h^2; newton-krylov, whose stopping
test is relative to the step's own scale, took every one down to 1e-8 h^2 (a new user's tau_tilde = 1e-8 had failed
with an IPOPT message that did not name it)."""
ANISOTROPY_INNER_MAX = 1e4
"""An anisotropy of scale s (the largest gamma(n) on unit normals; gamma0: 1, gamma1: 2) makes the inner step act as
tau_tilde s (gamma -> s gamma is tau_tilde -> s tau_tilde, the energies scaled): above this many h^2 the flow is
refused. A new user's gamma2:1e20 (s = 3e10, 3e8 h^2 at the default tau_tilde) exited 70 with a CHOLMOD traceback,
and after that was caught, the IPOPT fallback's attempts ran for more than 10 minutes on 642 vertices."""


@dataclass
class Stability:
    """The lowest eigenvalues of the energy's Hessian on normal motions (:meth:`WillmoreFlow.stability`).

    Attributes
    ----------
    eigenvalues : (k,) ascending, dimensionless (times L^4): a negative one is a saddle
    modes : (k, N, 3) their normal displacement fields (zero at fixed nodes), each with max |phi| = 1
    scale : L = sqrt(area / 4 pi) of the state
    gap : how far the energy is above the minimum of its quadratic model on these motions, relative to the energy
        (the Newton decrement; nan at a saddle): a state at rest on normal motions has a small one
    newton : (N, 3) the Newton step to that minimum (normal displacements on the constraints' tangent space; nan at a
        saddle)
    """

    eigenvalues: np.ndarray
    modes: np.ndarray
    scale: float
    gap: float
    newton: np.ndarray


@dataclass
class StepResult:
    """One accepted time step (or the initial state, with ``step == 0``).

    Attributes
    ----------
    step : step number k (0 for the initial state)
    t : time after the step
    tau : step size actually taken (smaller than nominal after retries)
    vertices : (N, m) positions X^k
    Y : (N, m) inner mean-curvature-motion step Y[X^k]
    objective : W at the solution
    energy : discrete energy of the scheme, 1/(2 tt^2) M(Y-X).(Y-X) + lam A (what decreases)
    willmore : independent discrete Willmore energy (:func:`willmore_nlp.geometry.willmore_energy`)
    willmore_gamma : anisotropic Willmore energy w_gamma = 1/2 int h_gamma^2
        (:func:`willmore_nlp.anisotropy.anisotropic_willmore_energy`; NaN for isotropic flows)
    measure : length or area
    volume : enclosed area or volume (NaN for open meshes)
    iterations : solver iterations
    converged : solver success
    status : solver status
    wall_time : seconds for the step, retries included
    quality : mesh-quality figures (:func:`willmore_nlp.geometry.quality`)
    retries : rejected attempts before the accepted one (tau is halved after each, except a first step's second
        failure under ``convex_start``; with a ``fallback_solver`` its attempts start again from the step's first tau)
    stats : solver statistics (evaluations, timings, KKT residual; ``rejected_iterations``: solver
        iterations spent on the step's rejected attempts; ``t_wall_control``: seconds of the mesh control
        after the accepted attempt, part of ``wall_time``; ``solver``: the solver that took the step)
    rejected : reasons of rejected attempts
    simplices : (K, d + 1) connectivity of the state (changes when the mesh control remeshes)
    free : (N,) bool free-vertex mask of a clamped problem on that connectivity (None without boundary)
    remeshed : the mesh-control action taken after this step ("" none; "flips", "repair", "smooth", "remesh",
        "refine", "saddle" / "polish" (a relaxation's move off a saddle / Newton polish of its minimum,
        ``relax_check``) joined by "+"); ``stats`` then holds
        ``energy_before_remesh`` and ``energy_after_remesh`` (the discrete energy) and ``willmore_before_remesh`` (the
        Willmore energy of the state the step reached)
    relaxed : True on the step that ended a relaxation (``relax=True``: the last steps changed the watched energy,
        the Willmore energy, the anisotropic one, or the scheme's energy with lam, c0 or outer constraints, by less
        than ``relax_tol`` relative)
    tau_tilde : inner step size of the state (lowered at rest by ``rest_tau_tilde``; Y is Y[X] for it)
    rest_steps : consecutive steps at rest counted toward the next halving of tau_tilde (``rest_tau_tilde``)
    """

    step: int
    t: float
    tau: float
    vertices: np.ndarray
    Y: np.ndarray
    objective: float
    energy: float
    willmore: float
    measure: float
    volume: float
    iterations: int
    converged: bool
    status: str
    wall_time: float
    quality: dict[str, float]
    retries: int = 0
    stats: dict[str, Any] = field(default_factory=dict)
    rejected: list[str] = field(default_factory=list)
    willmore_gamma: float = float("nan")
    simplices: np.ndarray | None = None
    free: np.ndarray | None = None
    remeshed: str = ""
    relaxed: bool = False
    tau_tilde: float = float("nan")
    rest_steps: int = 0

    def row(self) -> dict[str, Any]:
        """Flat dict for history.csv."""
        r = {
            "step": self.step,
            "t": self.t,
            "tau": self.tau,
            "objective": self.objective,
            "energy": self.energy,
            "willmore_energy": self.willmore,
            "willmore_gamma": self.willmore_gamma,
            "measure": self.measure,
            "volume": self.volume,
            "iterations": self.iterations,
            "converged": int(self.converged),
            "status": self.status,
            "wall_time": self.wall_time,
            "retries": self.retries,
            "rejected": " | ".join(self.rejected),
            "vertices": int(self.vertices.shape[0]),
            "remeshed": int(bool(self.remeshed)),
            "remesh_action": self.remeshed,
            "energy_before_remesh": self.stats.get("energy_before_remesh", float("nan")),
            "energy_after_remesh": self.stats.get("energy_after_remesh", float("nan")),
            "min_angle_before_remesh": self.stats.get("min_angle_before_remesh", float("nan")),
            "willmore_before_remesh": self.stats.get("willmore_before_remesh", float("nan")),
            "relaxed": int(self.relaxed),
            "tau_tilde": self.tau_tilde,
            "rest_steps": self.rest_steps,
            "solver": self.stats.get("solver", ""),
        }
        r.update({f"q_{k}": v for k, v in self.quality.items()})
        for k in ("kkt_residual", "t_wall_eval", "t_wall_solver", "t_wall_control", "n_eval_hess",
                  "energy_before_redistribution", "redistribution_shift", "rejected_iterations",
                  "n_cg", "n_factorizations", "t_wall_factor", "t_wall_cg", "n_guarded", "n_guard",
                  "drift_share", "dilation_undone", "stability", "stability_gap", "energy_before_move",
                  "willmore_before_move", "stability_gap_before_move", "mesh_pause", "mesh_slide"):
            # (n_cg to n_guard: newton-krylov's; n_guarded / n_guard: its guarded passes and the trial points their mesh
            # guard refused, which tell how many refusals a converged pass needs: GUARD_REFUSALS; drift_share and
            # dilation_undone: the drift rule's, DRIFT_SHARE; mesh_pause and mesh_slide: REST_SPEED's)
            if k in self.stats:
                r[k] = self.stats[k]
        return r


def check_scale(mesh: Mesh, solvers: Collection[str] = ()) -> float:
    """Refuse an initial mesh too wide (:data:`MAX_MESH_SIZE`) or too far from the origin (:data:`MAX_OFF_CENTRE`)
    for float64 and the solvers' tolerances (MeshError); warn when the absolute tolerances of one of ``solvers`` (the
    names of those that may run) do not suit its coordinates: IPOPT's far from the origin
    (:func:`ipopt_scale_trouble`), those of ``sqp`` and the reduced solvers also for widths below
    :data:`SMALL_MESH_SIZE` or above :data:`LARGE_MESH_SIZE`. Returns its width (the largest extent of its bounding
    box)."""
    V = mesh.vertices
    size = float(np.ptp(V, axis=0).max())
    if size > MAX_MESH_SIZE:
        raise MeshError(f"{mesh.source}: the mesh is {size:.3g} wide, beyond {MAX_MESH_SIZE:g} where the solver's "
                        f"absolute tolerances fail; rescale it to a size about 1 (Willmore flow is scale invariant: "
                        f"X -> X/L takes t -> t/L^4)")
    far = float(np.abs(V).max())
    if far > MAX_OFF_CENTRE * size:
        raise MeshError(f"{mesh.source}: the mesh lies {far:.3g} from the origin, {far / size:.3g} times its width "
                        f"{size:.3g}: its coordinates keep too few digits of its shape for the steps; move it to the "
                        "origin (Willmore flow is translation invariant)")
    absolute = set(solvers) - {"newton-krylov", "ipopt"}
    trouble = ipopt_scale_trouble(V) if set(solvers) - {"newton-krylov"} else ""
    if absolute and not trouble:
        trouble = (f"only {size:.3g} wide: the absolute tolerance of {', '.join(sorted(absolute))} is then met by "
                   "steps that barely move" if size < SMALL_MESH_SIZE else
                   f"{size:.3g} wide: the absolute tolerances of {', '.join(sorted(absolute))} are then too tight for "
                   "its coordinates" if size > LARGE_MESH_SIZE else "")
    if trouble:
        warnings.warn(f"{mesh.source}: the mesh is {trouble}; move it to the origin and rescale it to a size about 1 "
                      f"(Willmore flow is translation and scale invariant: X -> (X - c)/L takes t -> t/L^4) or set "
                      f"solver=newton-krylov (its tolerance is relative)", stacklevel=3)
    return size


def ipopt_scale_trouble(V: np.ndarray) -> str:
    """Why IPOPT's absolute tolerances do not suit the coordinates ``V`` (N, m) of a mesh ("" when they do): farther
    from the origin than :data:`OFF_CENTRE` widths (its width does not matter: IPOPT solves the steps of a mesh narrower
    or wider than :data:`SMALL_MESH_SIZE` and :data:`LARGE_MESH_SIZE` in the unit of length in which it is 2 wide,
    :func:`willmore_nlp.solvers.ipopt.length_unit`)."""
    size = float(np.ptp(V, axis=0).max())
    far = float(np.abs(V).max())
    if far > OFF_CENTRE * size:
        return (f"{far:.3g} from the origin, {far / size:.3g} times its width: IPOPT's absolute tolerances are then "
                "too tight for its coordinates")
    return ""


def _off_rest(lowest: float, gap: float) -> bool:
    """Whether a relaxed state whose lowest eigenvalue and gap on normal motions (:meth:`WillmoreFlow.stability`) are
    ``lowest`` and ``gap`` is not at rest there: no saddle, but a gap above :data:`POLISH_MAX_GAP` (nan: no)."""
    return lowest >= -SADDLE_TOL and gap > POLISH_MAX_GAP


def _check_quality(mesh: Mesh, min_angle: float, max_edge_ratio: float, repaired: str) -> None:
    """Refuse an initial mesh (after ``input_repair``, which did ``repaired``: "" for nothing) whose edge ratio or
    smallest angle is beyond the limits every step must keep, naming the simplex (MeshError)."""
    where = f"{mesh.source} (after input_repair's {repaired})" if repaired else mesh.source
    hint = "" if repaired else "remesh, or "
    ell = mesh.edge_lengths()
    if ell.max() / ell.min() > max_edge_ratio:
        raise MeshError(f"{where}: longest/shortest edge = {ell.max() / ell.min():.3g} exceeds max_edge_ratio = "
                        f"{max_edge_ratio:g}, which every step must keep: {hint}raise max_edge_ratio")
    if mesh.d == 2:
        ang = geometry.min_angles(mesh.vertices, mesh.simplices)
        k = int(np.argmin(ang))
        if ang[k] < min_angle:
            raise MeshError(f"{where}: triangle {k} (vertices {mesh.simplices[k].tolist()}) has an angle of "
                            f"{ang[k]:.3g} degrees, below min_angle = {min_angle:g} that every step must keep: "
                            f"{hint}lower min_angle")


def _sharp_edges(V: np.ndarray, F: np.ndarray, limit: float,
                 Vk: np.ndarray | None = None) -> tuple[int, tuple[int, int], float] | None:
    """The edges of the surface (V, F) in R^3 whose triangles' normals turn by more than ``limit`` degrees (and by more
    than with the positions ``Vk`` of the same triangles, when given): (how many, the sharpest's vertices, its angle),
    or None."""
    pairs, ends = edge_triangles(F)
    turn = geometry.dihedral_angles(V, F, pairs)
    over = turn > limit
    if Vk is not None and over.any():  # (Vk's angles only when some edge is past the limit: once per accepted step)
        over &= turn > geometry.dihedral_angles(Vk, F, pairs)
    if not over.any():
        return None
    i = int(np.argmax(np.where(over, turn, -1.0)))
    return int(np.count_nonzero(over)), (int(ends[i, 0]), int(ends[i, 1])), float(turn[i])


def _sharpens(V: np.ndarray, F: np.ndarray, V1: np.ndarray, F1: np.ndarray, limit: float) -> bool:
    """Whether (V1, F1), a repair or remeshing of the surface (V, F) in R^3 (the connectivities may differ), has an edge
    whose triangles' normals turn by more than ``limit`` degrees and more than any edge of (V, F)."""
    turn = geometry.dihedral_angles(V1, F1)
    top = float(turn.max()) if turn.size else 0.0
    return top > limit and top > float(geometry.dihedral_angles(V, F).max())


def _movable_turns(V: np.ndarray, F: np.ndarray, free: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """(E,) angles in degrees between the normals of the two triangles of the edges of (V, F) in R^3 that a remeshing
    of the ``free`` vertices can change (a triangle with a free vertex; every edge when ``free`` is None), and their
    (E, 2) end vertices: a clamped part's own creases are not the patch's to resolve."""
    pairs, ends = edge_triangles(F)
    if free is not None:
        keep = free[F[pairs]].reshape(len(pairs), -1).any(axis=1)
        pairs, ends = pairs[keep], ends[keep]
    return geometry.dihedral_angles(V, F, pairs), ends


def _warn_folds(mesh: Mesh, limit: float) -> None:
    """Warn when the initial surface ``mesh`` (in R^3) has edges whose triangles' normals turn by more than ``limit``
    degrees (``max_dihedral``): folds or creases that steps may keep or soften but not sharpen."""
    sharp = _sharp_edges(mesh.vertices, mesh.simplices, limit) if mesh.d == 2 and mesh.m == 3 else None
    if sharp is not None:
        over, (a, b), turn = sharp
        warnings.warn(f"{mesh.source}: {over} edge(s) whose triangles' normals turn by more than max_dihedral = "
                      f"{limit:g} deg (most at edge ({a}, {b}): {turn:.4g} deg), folds or sharp creases of the input: "
                      f"steps may keep or soften them but not sharpen them", stacklevel=3)


def _check_shape_kept(mesh: Mesh, X1: np.ndarray, F1: np.ndarray, what: str) -> None:
    """Refuse an ``input_repair`` remeshing (X1, F1) of ``mesh`` whose area differs by more than
    :data:`INPUT_SHAPE_CHANGE` of the input's: the input's features are thinner than the remeshing's edges."""
    a0 = float(geometry.simplex_volumes(mesh.vertices, mesh.simplices).sum())
    a1 = float(geometry.simplex_volumes(X1, F1).sum())
    if abs(a1 / a0 - 1) > INPUT_SHAPE_CHANGE:
        raise UserInputError(
            f"{mesh.source}: the input mesh is below the mesh control's thresholds, and {what} would change its shape "
            f"(area {a0:.4g} -> {a1:.4g}, {a1 / a0 - 1:+.0%}; {mesh.n_vertices} -> {len(X1)} vertices): it has "
            f"features thinner than its edges (mean edge {mesh.h:.3g}); give a finer mesh or a smaller --set "
            "remesh_target=H, or --set input_repair=false to flow it as given")


def _improves(before: dict[str, float], after: dict[str, float]) -> bool:
    """Patch quality ``after`` has a larger smallest angle or a smaller edge ratio than ``before``."""
    return after["min_angle"] > before["min_angle"] or after["edge_ratio"] < before["edge_ratio"]


def _free_of(boundary: Any) -> np.ndarray | None:
    """(N,) free-vertex mask of a clamp ``boundary``, or None without one."""
    return None if boundary is None else boundary.free


def _explicit(boundary: Any) -> bool:
    """A clamp with explicit co-normal or ring data (which a remeshing cannot carry to new vertices)."""
    return boundary is not None and (boundary.conormal is not None or boundary.ring is not None)


def _shortened(text: str, limit: int = 160) -> str:
    """``text`` cut at a word to at most ``limit`` characters, with "..." (a retry's reason in the progress bar: cut at
    a fixed character, "36 itera)" read as garbled)."""
    return textwrap.shorten(text, limit, placeholder="...")


def _target(value: float | str | None, name: str, mesh: Mesh) -> float | None:
    """Target of the ``volume`` or ``area`` option (validated by FlowSettings); "initial": the initial mesh's."""
    if value == "initial":
        return geometry.enclosed_volume(mesh) if name == "volume" else geometry.measure(mesh)
    return value  # type: ignore[return-value]


class WillmoreFlow:
    """Isotropic Willmore flow by the nested variational scheme (docs/theory/scheme.md).

    Parameters
    ----------
    mesh : Mesh
        Initial curve or surface (closed unless ``boundary`` is given).
    tau : float
        Outer time step (may be of the order of h).
    tau_tilde : float
        Inner mean-curvature step; keep it <= h^2 (larger values lose tangential convexity).
    lam : float
        Length/area energy weight (paper Sec. 5.2).
    boundary : Boundary, optional
        Clamped (C^1) boundary: which vertices move and which variant ("conormal" or "ring")
        imposes position and co-normal on the patch boundary (:mod:`willmore_nlp.boundary`).
        The fixed vertices never move; ``willmore`` in the results sums over the patch nodes.
    settings : FlowSettings, optional
        The flow's options as one object (default: :class:`~willmore_nlp.settings.FlowSettings`()),
        overridden by ``options``.
    terms : sequence of Term, optional
        Energy terms or outer constraints of the user's own (:class:`willmore_nlp.model.terms.Term`), added to the
        step problem the options build (docs/guide/terms.md, "A term of your own"); Python only.
    **options
        Flow options, the fields of :class:`~willmore_nlp.settings.FlowSettings` (``solver``,
        ``max_retries``, ``anisotropy``, ``tangential_weight``, ``relax``, ``remesh`` ...: see there
        or docs/reference/options.md), and the solver's options (``tol``, ``max_iter``, ``warm_start``,
        IPOPT options: :func:`willmore_nlp.solvers.solver_settings`). Each is validated when given. An option written
        ``NAME.KEY`` (``ipopt.max_iter``) is solver NAME's, whether NAME is ``solver``, ``first_step_solver``,
        ``fallback_solver`` or ``large_solver`` (refused when it is none of them), the others ``solver``'s
        (:func:`willmore_nlp.settings.solver_of`). IPOPT's options may also come as one mapping, like a config's
        ``[ipopt]`` table: ``ipopt={"max_iter": 10}`` is ``**{"ipopt.max_iter": 10}`` (an option given to one
        solver twice is refused).

    Attributes
    ----------
    stop_requested : callable () -> bool
        Asked before every attempt and (by IPOPT) once per solver iteration; when it returns
        True the step under way is abandoned and :meth:`step` raises :class:`StepInterrupted`
        instead of retrying (a truncated solve is never retried or accepted, so a stop never
        changes a result). The runner sets it from its signal handler.
    on_retry : callable (str) -> None
        Called before every attempt after a rejected one with a line saying what was rejected and what comes
        next (``"step 1: tau=0.05 rejected (ipopt: solver did not converge ...); attempt 2: ipopt at
        tau=0.025"``): the command line shows it in its progress bar, so that a first step of many minutes is
        not silent. Default: nothing.
    relax_newton : bool
        Whether this flow's relaxation takes Newton steps on normal motions (the setting ``relax_newton``; unset:
        a relaxation of a surface in R^3 does).
    """

    def __init__(self, mesh: Mesh, tau: float, tau_tilde: float, *, lam: float = 0.0, boundary: Any = None,
                 settings: FlowSettings | None = None, terms: Sequence[Term] = (), **options: Any) -> None:
        if not isinstance(mesh, Mesh):
            raise UserInputError(f"mesh must be a willmore_nlp.mesh.Mesh (Mesh(vertices, simplices) or "
                                 f"willmore_nlp.mesh.io.load_mesh(path)), got {type(mesh).__name__}")
        self._extra_terms = tuple(terms)
        for t in self._extra_terms:
            if not isinstance(t, Term):
                raise UserInputError(f"terms: each must be a willmore_nlp.model.terms.Term instance, got "
                                     f"{type(t).__name__}")
        flow_options, solver_options = FlowSettings.split(options)
        s = self.settings = dataclasses.replace(settings or FlowSettings(), **flow_options)  # validates them
        self._options = route_solver_options(flatten_ipopt(solver_options), {r: getattr(s, r) for r in SOLVER_ROLES})
        tau, tau_tilde, lam = (check_run_value(k, v) for k, v in (("tau", tau), ("tau_tilde", tau_tilde), ("lam", lam)))
        if not s.allow_components:
            from willmore_nlp.mesh.topology import check_connected

            check_connected(mesh, "set allow_components=true to flow them together")
        check_scale(mesh, self._solver_names())
        if boundary is not None:
            check_mask_size(mesh, boundary)
        self.mesh = mesh
        self.tau, self.tau_tilde, self.lam = tau, tau_tilde, lam
        t0 = time.perf_counter()
        if s.redistribute and not (mesh.d == 1 and mesh.is_closed and boundary is None):
            raise UserInputError(f"{mesh.source}: redistribute=True is implemented for closed curves without boundary "
                                 "conditions")
        if s.conformal_gauge and not (mesh.d == 2 and mesh.m == 3 and mesh.is_closed and boundary is None
                                      and s.volume is None and s.area is None):
            raise UserInputError(f"{mesh.source}: conformal_gauge=True is for closed surfaces in R^3 without boundary "
                                 "conditions or volume/area constraints")
        if s.relax_newton and not (s.relax and mesh.d == 2 and mesh.m == 3):
            raise UserInputError(f"{mesh.source}: relax_newton=True is how a relaxation of a surface in R^3 steps: it "
                                 "needs relax=True and a surface in R^3")
        # (unset: on for a relaxation of a surface in R^3)
        self.relax_newton = s.relax and mesh.d == 2 and mesh.m == 3 and s.relax_newton is not False
        self._tau_adapt = float("inf")  # first try of the next step under adaptive control
        # convex_start: the convexity limit tau_c of the first step (or of the first after a refinement) and the
        # restarts its Lanczos iteration had
        self._tau_c: tuple[float, int, int] | None = None  # convexity limit, its look's restarts, the step k of X^k
        self._refined_at = -1  # the step after which the mesh was last refined (-1: never)
        self.initial_mesh = mesh
        self._accepted_iterations: list[int] = []  # iteration counts of the last accepted steps
        self._start_warned = False  # a step accepted at its start by a loose tol was warned of (once per flow)
        self.relaxed = False
        self._t_end = float("inf")  # run(t_end=...): caps relax steps by what is left to it; a step that ends within
        # round-off of it ends on it
        self._run_tau: float | None = None  # run(t_end=...): the nominal tau, which it caps by what is left
        self._cut = False  # the step under way was shortened to land on t_end (the step-size control ignores it)
        self.remesh = (s.remesh == "auto" and s.mesh_control == "auto" and mesh.d == 2 and mesh.m == 3)
        self.k = 0  # (the input repair's warnings name the step)
        self._refinements = 0  # refinements so far (refine_dihedral): a given remesh_target is divided by REFINE_FACTOR
        # "initial" volume and area are the input's (a vesicle's reduced volume), also when input_repair remeshes it
        self._targets = {"volume": _target(s.volume, "volume", mesh), "area": _target(s.area, "area", mesh)}
        self.input_repair = ""  # what input_repair did to the initial mesh ("": nothing)
        self._input_min_angle = float("nan")  # the smallest angle of the input's patch, when input_repair acted
        if self.remesh and s.input_repair:
            mesh, boundary = self._repair_input(mesh, boundary)
        _check_quality(mesh, s.min_angle, s.max_edge_ratio, self.input_repair)  # the limits every step must keep
        _warn_folds(mesh, s.max_dihedral)
        # the anisotropy, built and validated once (every rebuild of the step problem after a remeshing uses it)
        self._anisotropy: Anisotropy | None = (None if s.anisotropy is None
                                                else get_anisotropy(s.anisotropy, mesh.m))
        self._step_scales(mesh)
        self._variational = all("variational" in solver_capabilities(n)  # the semi-implicit baseline is not
                                for n in self._solver_names())
        method = resolve_method(s.tangential_control, mesh, s.mesh_control, self._variational,
                                _free_of(boundary))
        weight = s.tangential_control_weight
        if weight is None:
            weight = default_weight(mesh, s.anisotropy, _free_of(boundary) is not None)
        elif method == "off" and s.tangential_control == "auto":  # (a weight given and silently unused on a noisy
            warnings.warn(f"{mesh.source}: tangential_control_weight = {weight:g} is not used: "  # trimesh cylinder)
                          "tangential_control = 'auto' leaves the in-step control off on this flow (as on curves, "
                          "closed surfaces of genus >= 1, meshes with sharp edges or spikes and with mesh_control = "
                          "off); tangential_control=meanratio turns it on", stacklevel=2)
        self._control = TangentialControl(method, weight, s.tangential_control_time)
        self.codegen_info: dict[str, Any] = {"enabled": False}
        codegen = s.codegen
        if codegen is None:
            codegen = find_compiler() is not None
            if not codegen:
                warnings.warn("no C compiler found: element kernels run in CasADi's virtual machine "
                              "(slower; set $CC or install gcc to compile them)", stacklevel=2)
        self._codegen = bool(codegen)
        self._compiled: dict[str, Any] | None = None
        self._kernel_maps: dict[tuple[str, bool], Any] = {}  # (the evaluators' mapped kernels, kept across rebuilds)
        self.stop_requested: Callable[[], bool] = _never
        self._stop_seen = False  # stop_requested() returned True during the step under way (see _stop)
        self.on_retry: Callable[[str], None] = _ignore
        self._length_unit = length_unit(mesh.vertices)  # (IPOPT's, for every step: a scaled mesh scales it)
        self._build(mesh, boundary)
        for other in self._solver_names() - {self.solver.name}:  # their errors now, not at their first step
            check_solver(other, self.problem, self._solver_options(other))
        self.build_time = time.perf_counter() - t0
        self._check_isoperimetric(mesh)
        try:
            self.X = self._restore(np.array(mesh.vertices, float))
        except (RuntimeError, np.linalg.LinAlgError) as exc:
            held = [t.label for t in self.problem.terms if t.constraint_targets]
            raise UserInputError(f"{mesh.source}: the initial mesh cannot be moved onto the outer constraints "
                                 f"({', '.join(held)}; {exc})") from exc
        self._check_restored(mesh)
        self.t = 0.0
        try:
            self.Y = self._solve_y(self.X, self.tau)
        except RuntimeError as exc:
            raise MeshError(f"{mesh.source}: the inner mean-curvature step Y[X] cannot be solved on the initial "
                            f"mesh ({exc}); look for nearly degenerate simplices or an extreme scale") from exc
        self.lam_g: np.ndarray | None = None
        e0 = self.discrete_energy(self.X, self.Y)
        if not np.isfinite(e0):
            raise UserInputError(f"{mesh.source}: the step's energy at the initial state is {e0} (terms: "
                                 f"{', '.join(t.label for t in self.problem.terms)}): a term is not finite there")
        # the energy is the Willmore energy's, Moebius invariant: no lam, and no term that changes W otherwise (c0,
        # an anisotropy, a term of the user's: a user's surface tension had its dilation undone by the drift rule)
        invariant = lam == 0 and all(t.moebius_invariant for t in self.problem.terms)
        self._moebius = invariant
        foreign = [t.label for t in self._extra_terms if not t.moebius_invariant]
        if s.conformal_gauge and foreign:  # (asked for with lam, c0 or an anisotropy it is the user's choice)
            raise UserInputError(f"{mesh.source}: conformal_gauge=True undoes the motion along the Willmore energy's "
                                 f"Moebius zero modes, which the terms {', '.join(foreign)} do not declare "
                                 "(moebius_invariant = False)")
        # relax=true watches the energy the flow decreases: W, or with lam A, c0 or an anisotropy the scheme's energy
        # (a c0 vesicle "relaxed" on a rise of W while its Helfrich energy still fell 2e-4 per step: a new-user check)
        # scale invariant: W, or an anisotropic W, without lam, c0, a user's term or outer constraints; relax=true then
        # watches the anisotropic W (e falls with the drift at rest: the anisotropic sphere's relaxation never ended
        # on e with two BLAS threads and collapsed at step 35)
        self._scale_invariant = not self.problem.nh and (invariant or (lam == 0 and s.c0 == 0 and all(
            t.moebius_invariant for t in self._extra_terms)))
        self._relax_column = ("willmore_energy" if invariant or not s.relax else "willmore_gamma"
                              if self._scale_invariant and self.setup.anisotropy is not None else "energy")
        self.relax_reason = ""  # why relax=true ended: "small" (change below relax_tol) or "rose" (drift at rest)
        self._kicks = 0  # saddles left (relax_check; counted by the relax test, replayed on restart)
        self._go_ons = 0  # window ends gone past, the state not at rest (MAX_GO_ON; replayed on restart)
        self.last_stability = self.last_gap = float("nan")  # stability()'s lowest eigenvalue and gap when a
        # relaxation last ended
        self.untested = ""  # why that test failed ("": it ran, or did not run)
        self._spectral: Any = None  # stability()'s reduced solver in a flow whose step solver is not one
        self._saddle_mode = self._newton = np.zeros_like(self.X)
        self._relax_start(self._relax_value(self.X, self.Y))
        self._X_prev = self.X
        self._paused = False  # a healthy state at rest: light repair and in-step control paused (REST_SPEED)
        self._drifting = False  # a paused step moved the nodes too fast: no more pauses (REST_SPEED)
        self._slide = 0.0  # while paused: the last step's speed, which a paused step may not exceed (REST_SPEED)
        # the scheme's drift of closed surfaces with mesh control and no outer constraint (a scale to drift along)
        drifts = self.remesh and boundary is None and mesh.is_closed and not self.problem.nh
        # rest_tau_tilde: at rest (see _rest_tau_tilde)
        self.tau_tilde_initial = self.tau_tilde
        self._rest = drifts and not s.relax and s.rest_tau_tilde < 1
        self._rest_steps = 0
        self._rest_w = self._relax_window[0][0]
        # the drift told by the motion (DRIFT_SHARE), also in relax mode (whose growing steps drift the most), where the
        # energy is Moebius invariant, so that the ten conformal fields are its zero modes (not with lam A, c0 or an
        # anisotropy: lengths, directions)
        self._drift_rule = drifts and invariant  # (drifts: no outer constraint)

    def _build(self, mesh: Mesh, boundary: Any) -> None:
        """Step problem, evaluator and solver for the connectivity of ``mesh``.

        Called once at construction and after every connectivity change: the element kernels
        (and their compiled C library) are the same, only the assembly patterns are new.
        """
        self.mesh = mesh
        self.boundary = boundary
        self._h_scale: np.ndarray | None = None  # the outer constraints' own scales on it (constraint_violation)
        self.setup = build_step(mesh, boundary=boundary, anisotropy=self._anisotropy,
                                tangential_weight=self.settings.tangential_weight, tangential_control=self._control,
                                c0=self.settings.c0, extra_terms=self._extra_terms, **self._targets)
        self.problem = self.setup.problem
        bd = self.setup.boundary
        self.energy_nodes: np.ndarray | None = None if bd is None else bd.patch_nodes
        kernels = self.problem.kernels
        if self._codegen and self._compiled is None:
            self.codegen_info = {"enabled": True}
            try:
                self._compiled = compile_kernels(self.problem.kernels, info=self.codegen_info)
            except OSError as exc:  # not even a temporary directory is writable
                self._codegen = False
                self.codegen_info = {"enabled": False, "error": str(exc)}
                warnings.warn(f"cannot compile the element kernels ({exc}): they run in CasADi's virtual machine "
                              f"(slower); set codegen=false to skip compiling", stacklevel=3)
        if self._compiled is not None:
            kernels = self._compiled
        self.evaluator = StepEvaluator(self.problem, self.problem.functions(kernels), self._kernel_maps)
        if self.relax_newton:  # Y[X] of the Newton steps' trials and of the mesh control by the sparse Cholesky
            self.evaluator.cholesky = "auto"  # of the N x N block: 2,562 v, 0.30 -> 0.26 s per step
        self._make_solver(self._step_solvers()[0])

    def _solver_names(self) -> set[str]:
        """Every solver the flow may use: ``solver``, ``first_step_solver``, ``fallback_solver`` and
        ``large_solver``."""
        s = self.settings
        return {n for n in (s.solver, s.first_step_solver, s.fallback_solver, s.large_solver) if n}

    def main_solver(self, n_vertices: int) -> str:
        """The solver of a step that starts on a mesh of ``n_vertices`` vertices: ``large_solver`` from
        ``large_vertices`` on (when set), else ``solver``."""
        s = self.settings
        return s.large_solver if s.large_solver and n_vertices >= s.large_vertices else s.solver

    def budget_iterations(self, rows: list[dict[str, Any]]) -> list[int]:
        """The iteration counts that the iteration budget of a run with the history ``rows`` (from the initial
        state on, as in history.csv) was taken from: those of the steps whose solver was the main solver
        (:meth:`main_solver`) of the mesh they started from (the previous row's vertices), the last
        ``BUDGET_WINDOW``."""
        counts, n = [], None
        for r in rows:
            main = self.settings.solver if n is None else self.main_solver(n)
            if int(float(r["step"])) > 0 and "iterations" in r and r.get("solver") in (None, "", main):
                counts.append(int(float(r["iterations"])))
            n = int(float(r["vertices"])) if r.get("vertices") not in (None, "") else None
        return counts[-BUDGET_WINDOW:]

    def _step_solvers(self) -> tuple[str, ...]:
        """The solvers of the next step, in turn: ``first_step_solver`` (when set) for the first step, else the
        main solver of the current mesh (:meth:`main_solver`); then ``fallback_solver`` (when set and not that
        one; else ``solver`` after a ``large_solver``) if every attempt of the first fails."""
        s = self.settings
        main = self.main_solver(self.mesh.n_vertices)
        first = s.first_step_solver if self.k == 0 and s.first_step_solver else main
        fallback = s.fallback_solver or (s.solver if main != s.solver else "")
        return (first,) if fallback in ("", first) else (first, fallback)

    def _solver_options(self, name: str) -> dict[str, Any]:
        """The solver options of ``name``, one of the flow's solvers: the ``NAME.KEY`` ones and, for ``solver``, the
        others (:func:`~willmore_nlp.settings.solver_of`)."""
        return dict(self._options[name])

    def _make_solver(self, name: str) -> None:
        """``self.solver``: the solver ``name`` for the current step problem, with the flow's stop and stall tests."""
        self.solver = make_solver(name, self.evaluator, self._solver_options(name))
        self.solver.should_stop = lambda: self._stop()
        if hasattr(self.solver, "stall_iterations"):
            self.solver.stall_iterations = self.settings.stall_iterations
        if hasattr(self.solver, "length"):
            self.solver.length = self._length_unit

    @property
    def tangential_control(self) -> TangentialControl:
        """The in-step tangential control this flow runs (``tangential_control = "auto"`` resolved)."""
        return self._control

    @property
    def free(self) -> np.ndarray | None:
        """(N,) free-vertex mask of the current connectivity (None without clamped boundary)."""
        return _free_of(self.setup.boundary)

    # -- helpers -----------------------------------------------------------------------
    def constraint_violation(self, X: np.ndarray) -> float:
        """Largest relative residual |h_i| / s_i of the outer constraints at X (0 without any): s_i = |target_i|, or
        where that is smaller the change of h_i when every vertex moves by the mean edge h, ``|dh_i/dX| h`` at the
        first X asked on the current connectivity (a target 0, e.g. a fixed centroid, had no scale: every residual
        was inf, and a target of round-off size 4e-16 made 1e-16 a relative 0.29; a remeshing sets it anew)."""
        P = self.problem
        if not P.nh:
            return 0.0
        p = self._x_params(X, self.tau)
        h = self.evaluator.h(P.pack_z(X, X), p)
        targets = np.abs([P.params.scalar(p, t) for t in P.targets])
        if self._h_scale is None or len(self._h_scale) != len(targets):
            Jc = self.evaluator.c_jac(P.pack_z(X, X), p)[1].tocsr()[P.ng:, : P.nX * P.m]
            self._h_scale = np.sqrt(np.asarray(Jc.multiply(Jc).sum(axis=1)).ravel()) * self.mesh.h
        return float(np.max(np.abs(h) / np.maximum(targets, self._h_scale)))

    def _check_isoperimetric(self, mesh: Mesh) -> None:
        """Refuse volume and area targets that no closed surface (curve) has: the isoperimetric inequality
        36 pi V^2 <= A^3 (4 pi A <= L^2 of a plane curve), equal only for the round sphere (circle), which no mesh is.
        Volume 8 with area 19 (reduced volume 1.027) failed only in :meth:`_restore` ("cannot be moved onto the outer
        constraints", relative residual 2.0 from the sphere problem's icosphere; a new-user check). Called after the
        terms' checks: both targets are positive and the mesh is closed."""
        V, A = self._targets["volume"], self._targets["area"]
        if V is None or A is None:
            return
        if mesh.d == 1:
            ratio, of = 4 * math.pi * V / A**2, "4 pi A / L^2"
            law = "4 pi A <= L^2 (equal only for a circle, which no polygon is)"
        else:
            ratio, of = shapes.reduced_volume(A, V), "the reduced volume 6 sqrt(pi) V / A^1.5"
            law = "36 pi V^2 <= A^3 (equal only for a round sphere, which no mesh is)"
        if ratio >= 1:
            curve = " (a curve's enclosed area and length)" if mesh.d == 1 else ""
            raise UserInputError(f"{mesh.source}: volume = {V:.6g} and area = {A:.6g}{curve} are impossible targets: "
                                 f"the isoperimetric inequality {law} bounds {of} by 1, and they give {ratio:.4g}; "
                                 "lower the volume or raise the area")

    def _check_restored(self, mesh: Mesh) -> None:
        """Refuse volume/area targets so far from the initial mesh's own that moving it onto them (:meth:`_restore`)
        halves its smallest angle: measured on a 642-v ellipsoid (35.8 deg; area held), volume 0.9 and 0.8 of its
        own move a vertex by 1.6 and 2.9 mean edges and leave 29.6 and 24.4 deg, 0.7 leaves 4.0 deg with a 74-deg
        fold, and a volume of 3 instead of 6.64 left 0.54 deg and a 178-deg fold, whose run failed after 18
        attempts (a new-user check)."""
        if not self.problem.nh or mesh.d != 2:
            return
        before = float(geometry.min_angles(mesh.vertices, mesh.simplices).min())
        after = float(geometry.min_angles(self.X, mesh.simplices).min())
        if after < 0.5 * before:
            own = {"volume": geometry.enclosed_volume(mesh), "area": geometry.measure(mesh)}
            move = float(np.linalg.norm(self.X - mesh.vertices, axis=1).max()) / mesh.h
            targets = ", ".join(f"{k} {v:.4g} (its own {own[k]:.4g})" for k, v in self._targets.items()
                                if v is not None)
            raise UserInputError(f"{mesh.source}: volume/area targets far from the initial mesh's own ({targets}): "
                                 f"moving it onto them moves a vertex by {move:.2g} mean edges and leaves a smallest "
                                 f"angle of {after:.2g} deg ({before:.3g} before); start from a mesh nearer the "
                                 "targets, or use \"initial\"")

    def _restored(self, X: np.ndarray, X1: np.ndarray, tau: float, same: bool) -> tuple[np.ndarray, np.ndarray]:
        """(X1, Y[X1]): the repair X1 of the state X moved back onto the outer constraints (volume, area) on the mesh
        built for it. A least-norm correction that moves a vertex by more than ``RESTORE_LIMIT`` h builds spikes; a
        repair of the same vertices (``same``: no remeshing) is then shortened, X + (X1 - X) / 2^j for j up to
        ``RESTORE_HALVINGS``, before it is given up (ArithmeticError, as for a Y[X] that is not finite)."""
        for j in range(RESTORE_HALVINGS + 1 if same else 1):
            Xj = X1 if not j else X + (X1 - X) / 2**j
            Xr = self._restore(Xj)
            shift = float(np.abs(Xr - Xj).max())
            if shift <= RESTORE_LIMIT * self.mesh.h:
                Y1 = self._solve_y(Xr, tau)
                if not np.all(np.isfinite(Y1)):
                    raise ArithmeticError("Y[X] has non-finite values")
                return Xr, Y1
        raise ArithmeticError(f"restoring volume/area moved a vertex by {shift / self.mesh.h:.3g} h")

    def _restore(self, X: np.ndarray) -> np.ndarray:
        """X moved onto the outer constraints (volume, area: functions of X only) by least-norm
        Gauss-Newton steps ``-Jh^T (Jh Jh^T)^-1 h``; X itself without outer constraints."""
        P = self.problem
        for _ in range(30):
            if self.constraint_violation(X) <= 1e-13:
                return X
            p = self._x_params(X, self.tau)
            c, Jc = self.evaluator.c_jac(P.pack_z(X, X), p)
            Jh = Jc.tocsr()[P.ng :, : P.nX * P.m].toarray()
            X = P.unpack_x(X[P.x_free].ravel() - Jh.T @ np.linalg.solve(Jh @ Jh.T, c[P.ng :]), X)
        raise RuntimeError(f"outer constraints not restored (relative residual {self.constraint_violation(X):.3e})")

    def params(self, Xk: np.ndarray, tau: float, off: Collection[str] = ()) -> np.ndarray:
        """Parameter vector of a step from Xk with step size tau (``off``: terms left out,
        :meth:`~willmore_nlp.model.step.StepProblem.pack_p`)."""
        return self.setup.params(Xk, tau, self.tau_tilde, self.lam, off)

    def _x_params(self, X: np.ndarray, tau: float) -> np.ndarray:
        """Parameters for the functions of X alone (the inner solve Y[X], the outer constraints): the tangential
        control, an outer term, is left out (its per-node data cost four mean-ratio sub-steps)."""
        return self.params(X, tau, CONTROL_OFF)

    def _solve_y(self, X: np.ndarray, tau: float, Y0: np.ndarray | None = None) -> np.ndarray:
        return self.evaluator.solve_y(X, self._x_params(X, tau), Y0)

    def discrete_energy(self, X: np.ndarray, Y: np.ndarray | None = None) -> float:
        """``e(X) = 1/(2 tt^2) M[X](Y[X]-X).(Y[X]-X) + lam A[X]``, the energy the scheme decreases (with ``c0``:
        ``1/2 int |(Y[X] - X)/tt + c0 n|^2 + lam A[X]``): W at X^k = X, where the distance term vanishes and the
        tangential control's term (which does not: its target S is not 0) is left out."""
        p = self.params(X, 1.0, CONTROL_OFF)
        Y = self.evaluator.solve_y(X, p) if Y is None else Y
        return self.evaluator.f(self.problem.pack_z(X, Y), p) / 2.0

    def stability(self, count: int = 2, method: str = "auto") -> Stability:
        """The lowest eigenvalues of the scheme's energy's Hessian on normal motions of the current state: is it a
        minimum (all positive) or a saddle (a negative one, whose mode lowers the energy)?

        :func:`~willmore_nlp.solvers.reduced.normal_spectrum` at X^k = X: the L^2 Hessian of e (:meth:`discrete_energy`)
        on normal displacements phi n of the free nodes, on the tangent space of the outer constraints (with their
        multipliers) and, for a closed surface, without the normal parts of the motions its energy does not see:
        the translations, the rotations (isotropic energies), the dilation (scale-invariant energies: W or an
        anisotropic W without lam, c0 or outer constraints) and the special conformal fields (a Moebius-invariant
        energy without outer constraints). The eigenvalues are made dimensionless by L^4 (L^2 =
        area / 4 pi; on a round sphere they tend to 24: 24.53 / 24.13 at 642 / 2,562 vertices at the defaults'
        tau_tilde = h^2 / 100, other values at another tau_tilde,
        :func:`~willmore_nlp.solvers.reduced.normal_spectrum`). Meaningful where the state is at rest (the gradient
        near 0); for surfaces in R^3 of at most :data:`STABILITY_MAX_VERTICES` vertices (dense up to
        :data:`~willmore_nlp.solvers.reduced.SPECTRUM_DENSE_MAX` free nodes, above matrix-free).

        Parameters
        ----------
        count : how many of the lowest eigenvalues; above the number of normal motions (the free nodes less the motions
            left out) all of them (``eigenvalues`` is then shorter than ``count``)
        method : "auto", "dense" or "iterative" (:func:`~willmore_nlp.solvers.reduced.normal_spectrum`; auto: dense up
            to :data:`~willmore_nlp.solvers.reduced.SPECTRUM_DENSE_MAX` free nodes)

        Returns
        -------
        Stability

        Raises
        ------
        ArithmeticError
            When the iterative eigensolver or the Newton step's CG does not converge (a relaxation's check then says
            the state was not tested, and why)
        """
        mesh = self.mesh.with_vertices(self.X)
        if mesh.d != 2 or mesh.m != 3:
            raise UserInputError("stability(): surfaces in R^3 only")
        if isinstance(count, bool) or not isinstance(count, int | np.integer) or count < 1:
            raise UserInputError(f"stability(): count must be an integer >= 1, got {count!r}")
        if method not in ("auto", "dense", "iterative"):
            raise UserInputError(f"stability(): method must be 'auto', 'dense' or 'iterative', got {method!r}")
        if mesh.n_vertices > STABILITY_MAX_VERTICES:
            raise UserInputError(f"stability(): {mesh.n_vertices} vertices, above STABILITY_MAX_VERTICES = "
                                 f"{STABILITY_MAX_VERTICES}")
        return self._normal_spectrum(count, method)

    def _normal_spectrum(self, count: int, method: str) -> Stability:
        """:meth:`stability` without its checks of the input; ``count = 0``: the gap and the Newton step alone (nan
        where CG finds no minimum of the quadratic model)."""
        from willmore_nlp.solvers.reduced import ReducedSolver, normal_spectrum

        mesh = self.mesh.with_vertices(self.X)

        free = self.problem.x_free
        n = geometry.vertex_normals(mesh)
        fields = None
        if self.boundary is None:  # the symmetries of the energy: translations, rotations, dilation, Moebius
            B = geometry.conformal_normals(mesh, n)[0]
            # (the dilation of a scale-invariant energy: the anisotropic sphere's had an eigenvalue of -0.23, and the
            # move along it sped up its drift)
            keep = [*range(3), *(range(3, 6) if self.setup.anisotropy is None else ()),
                    *([6] if self._scale_invariant else ()), *(range(7, 10) if self._scale_invariant and self._moebius
                                                               else ())]
            fields = B[np.ix_(free, keep)]
        p = self.params(self.X, 1.0, CONTROL_OFF)
        solver = self.solver if isinstance(self.solver, ReducedSolver) else self._spectrum_solver()
        z = self.problem.pack_z(self.X, self.Y)
        mu, phi, gap, newton = normal_spectrum(self.evaluator, z, p, n[free], fields, count, solver, method)
        L = geometry.length_scale(geometry.measure(mesh), 2, True)
        modes = np.zeros((len(mu), *self.X.shape))
        modes[:, free] = phi.T[:, :, None] * n[free][None]
        step = np.zeros_like(self.X)
        step[free] = newton[:, None] * n[free]
        return Stability(eigenvalues=mu * L**4, modes=modes, scale=L,
                         gap=gap / abs(self.discrete_energy(self.X, self.Y)), newton=step)

    def state(self) -> StepResult:
        """The current state as a StepResult (step 0 style, no solver data; at step 0 ``remeshed`` says what
        ``input_repair`` did to the initial mesh)."""
        r = self._result(self.X, self.Y, self.tau, float("nan"), None, 0.0, 0, [])
        r.remeshed = self.input_repair if self.k == 0 else ""
        if r.remeshed:  # (the input's smallest angle, as a step's row has its stepped state's)
            r.stats["min_angle_before_remesh"] = self._input_min_angle
        return r

    def _result(self, X: np.ndarray, Y: np.ndarray, tau: float, obj: float, res: Any,
                wall: float, retries: int, rejected: list[str]) -> StepResult:
        mesh = self.mesh.with_vertices(X)
        return StepResult(
            step=self.k,
            t=self.t,
            tau=tau,
            vertices=X.copy(),
            Y=Y.copy(),
            objective=obj,
            energy=self.discrete_energy(X, Y),
            willmore=geometry.willmore_energy(mesh, self.energy_nodes),
            measure=geometry.measure(mesh),
            volume=geometry.enclosed_volume(mesh),
            iterations=0 if res is None else res.iterations,
            converged=True if res is None else res.converged,
            status="initial" if res is None else res.status,
            wall_time=wall,
            quality=geometry.quality(mesh),
            retries=retries,
            stats={} if res is None else dict(res.stats),
            rejected=rejected,
            willmore_gamma=(float("nan") if self.setup.anisotropy is None
                            else anisotropic_willmore_energy(mesh, self.setup.anisotropy, self.energy_nodes)),
            simplices=self.mesh.simplices,
            free=self.free,
            tau_tilde=self.tau_tilde,
            rest_steps=self._rest_steps,
        )

    def _reject_reason(self, res: Any, f0: float, X: np.ndarray) -> str | None:
        if not res.converged:  # (IPOPT's acceptable level read "did not converge (Solved_To_Acceptable_Level": a
            # contradiction to a new user; the step needs tol, not the looser acceptable_tol)
            looser = " to tol, only to IPOPT's looser acceptable level" if "Acceptable" in str(res.status) else ""
            return f"{SOLVER_REASON}{looser} ({res.status}, {res.iterations} iterations)"
        if not np.all(np.isfinite(X)):
            return "non-finite positions"
        violation = self.constraint_violation(X)
        if violation > CONSTRAINT_RTOL_SOLVER:
            return f"outer constraint violated by {violation:.3g} (relative) > {CONSTRAINT_RTOL_SOLVER:g}"
        bound = f0 + self.settings.energy_rtol * abs(f0) + 1e-14
        if self.settings.check_energy and self._variational and res.f > bound:
            return f"energy inequality violated: W = {res.f:.12g} > W(X^k) = {f0:.12g}"
        try:
            q = geometry.quality(self.mesh.with_vertices(X))
        except MeshError as exc:
            return f"mesh collapsed: {exc}"
        if q["edge_ratio"] > self.settings.max_edge_ratio:
            return f"{EDGE_RATIO_REASON} {_past(q['edge_ratio'], self.settings.max_edge_ratio)} > " \
                   f"{self.settings.max_edge_ratio:g}"
        if "min_angle" in q and q["min_angle"] < self.settings.min_angle:
            return f"mesh quality: min angle {_past(q['min_angle'], self.settings.min_angle)} deg < " \
                   f"{self.settings.min_angle:g}"
        return self._fold(X, q)

    def _grown(self, tau: float) -> bool:
        """Whether an attempt at ``tau`` is a grown step: above the last accepted step size (the ``adaptive`` or
        ``relax`` control's doubling; never the first step)."""
        return self.k > 0 and 0 < self._last_tau < tau

    def _crushes(self, X: np.ndarray, fall: float) -> str | None:
        """Why a grown step to X is refused (it is then retried at the last accepted size), or None: with the mesh
        control on, the step lowers the step objective by less than :data:`GROWN_FALL` of itself (``fall``, relative)
        and takes the patch's smallest angle below ``remesh_min_angle`` from a state at or above it. Such a step buys
        its size with the mesh: the remeshing that follows lifts W by more than the step lowered it, where the step at
        the last size keeps the mesh."""
        fell = None if fall >= GROWN_FALL else self._angle_fall(X)
        if fell is None:
            return None
        limit = self.settings.remesh_min_angle
        return f"{GROWN_REASON}: its smallest angle {fell[0]:.3g} deg < remesh_min_angle = {limit:g}"

    def _collapses(self, X: np.ndarray) -> str | None:
        """Why the step to X is retried at tau / 2 for the mesh's sake, or None: with the mesh control on, it takes the
        patch's smallest angle below :data:`COLLAPSE_FRACTION` x ``remesh_min_angle`` from a state at or above
        ``remesh_min_angle``. Such a step is too long for the mesh: its slivers carry a discrete energy that the
        remeshing does not keep (a thin torus's first step: W 37.3 below 4 pi^2, 54.8 after the remeshing)."""
        floor = COLLAPSE_FRACTION * self.settings.remesh_min_angle
        fell = self._angle_fall(X)
        if fell is None or fell[0] >= floor:
            return None
        return (f"{COLLAPSE_REASON}: its smallest angle {fell[0]:.3g} deg < {floor:.3g} deg "
                f"({COLLAPSE_FRACTION:.3g} remesh_min_angle) from {fell[1]:.3g} deg")

    def _angle_fall(self, X: np.ndarray) -> tuple[float, float] | None:
        """(after, before): the patch's smallest angle at X and at X^k when, with the mesh control on, the step to X
        takes it from at or above ``remesh_min_angle`` to below it (:meth:`_crushes`, :meth:`_collapses`), else
        None."""
        if not self.remesh:
            return None
        F, limit = self.mesh.simplices, self.settings.remesh_min_angle
        after = self._patch_quality(X, F, self.free)["min_angle"]
        if after >= limit:
            return None
        before = self._patch_quality(self.X, F, self.free)["min_angle"]
        return (after, before) if before >= limit else None

    def _fold(self, X: np.ndarray, q: dict[str, float]) -> str | None:
        """Why the step to X (quality ``q``) folds the mesh (an edge whose triangles' normals turn by more than
        ``max_dihedral`` and more than in X^k: its vertices, its midpoint in X, the angle), or None."""
        limit = self.settings.max_dihedral
        sharp = _sharp_edges(X, self.mesh.simplices, limit, self.X) if q.get("max_dihedral", 0.0) > limit else None
        if sharp is None:
            return None
        _, (a, b), turn = sharp
        near = ", ".join(f"{c:.3g}" for c in X[[a, b]].mean(axis=0))
        return (f"{FOLD_REASON}: the normals of the triangles at edge ({a}, {b}) near ({near}) turn by {turn:.4g} "
                f"deg > max_dihedral = {limit:g}")

    # -- stepping ----------------------------------------------------------------------
    def _stop(self) -> bool:
        """:attr:`stop_requested`, latched for the step under way: once it has returned True (say, in IPOPT's
        iteration callback, which then cuts the solve), the step is abandoned even when a later call returns False (a
        callable that is True once, e.g. a request read from a queue); before, the cut solve was taken for a failed one
        and retried at tau / 2 (or its state was used by the first step's recovery), which changed the result."""
        if not self._stop_seen and self.stop_requested():
            self._stop_seen = True
        return self._stop_seen

    def step(self) -> StepResult:
        """Advance by one step of size tau; retry with tau/2 (at most ``max_retries`` times), then, when every
        attempt failed and a ``fallback_solver`` is set, with that solver from the first tau again.

        An attempt is rejected when the solver fails (raises, does not converge or returns
        non-finite values), the energy inequality is violated, the mesh collapses or its
        quality drops below the thresholds, or the inner equation Y[X] cannot be solved.

        Raises
        ------
        FlowError
            When every attempt was rejected; the flow's state is unchanged.
        StepInterrupted
            When :attr:`stop_requested` turned True and the attempt under way did not succeed
            (no retry follows); the flow's state is unchanged.
        """
        t0 = time.perf_counter()
        self._stop_seen = False
        if self.settings.relax:
            grown = self.tau if np.isinf(self._tau_adapt) else self._tau_adapt
            tau = min(self.relax_max_tau, self._t_end - self.t, grown)
            if self.relax_newton and self._spectrum_fits():
                newton = self._newton_relax_step(tau, t0)
                if newton is not None:
                    return newton
        else:
            tau = min(self.tau, self._tau_adapt) if self.settings.adaptive else self.tau
        self._cut = self._cut_by_t_end(tau, self.tau if self._run_tau is None else self._run_tau, self._new_state())
        rejected: list[str] = []
        spent = 0  # solver iterations of this step's attempts
        floor = min(self.min_tau, self.tau)
        below: float | None = None  # a step size that fell below min_tau
        tau0, tries = tau, -1  # tries: attempts so far (the step's retries when it is accepted)
        smallest = tau  # the smallest step size attempted
        solvers = self._step_solvers()
        start = None  # the first step's step size below tau_c, when the first look finds it far below tau
        for name in solvers:
            if self.solver.name != name:  # after a first step of first_step_solver, or the fallback_solver's turn
                self._make_solver(name)
            if self._new_state() and name == solvers[0] == "newton-krylov" and self.settings.max_retries \
                    and not self.problem.nh:  # (outer constraints: below tau_c only for the last attempt, see below)
                start = self._convex_start(tau0, 0)  # (its failed attempts are the costly ones: look first)
                tau_c = self._convex_far(tau0) if start is None and len(solvers) > 1 else None
                if tau_c is not None:
                    warnings.warn(f"step {self.k + 1}: the step problem is convex at {self._state_name()} only "
                                  f"below tau = {tau_c:.3g}, under the step-size floor min_tau = {floor:.3g}: "
                                  f"{solvers[1]} takes the step", stacklevel=2)
                    rejected.append(f"tau={tau0:.6g}: {name}: {SKIP_REASON} = {floor:.3g}")
                    continue  # (its attempts failed at tau / 2^j, all far above tau_c: the fallback's turn)
            tau = tau0 if start is None else start
            for attempt in range(self.settings.max_retries + 1):
                tries += 1
                if self._stop():
                    raise StepInterrupted(self.k + 1)
                if tau < floor:
                    rejected.append(f"tau={tau:.6g}: {FLOOR_REASON} = {floor:.3g}")
                    below = tau
                    break
                if rejected:
                    self.on_retry(f"step {self.k + 1}: {_shortened(rejected[-1].replace(': ', ' rejected (', 1))}); "
                                  f"attempt {tries + 1}: {name} at tau={tau:.3g}")
                smallest = min(smallest, tau)
                X, Y, res, reason, moved = self._attempt(tau, attempt >= self.settings.max_retries)
                spent += res.iterations if res is not None else 0
                if reason is None:
                    return self._accept(X, Y, tau, res, moved, t0, tries, rejected, spent)
                if self._stop():  # the solve was cut short (or failed): do not retry
                    raise StepInterrupted(self.k + 1)
                rejected.append(f"tau={tau:.6g}: {name + ': ' if len(solvers) > 1 else ''}{reason}")
                last = attempt == self.settings.max_retries
                # with outer constraints tau_c is a lower bound (convexity_limit) and only the last attempt goes below
                # it: a vesicle cup (v = 0.55, 642 v, tau_c = tau / 128) takes its first step at tau / 4
                looks = attempt == self.settings.max_retries - 1 if self.problem.nh else attempt <= 1
                jump = self._convex_start(tau0, min(attempt + 1, 2)) if looks and self._new_state() and start is None \
                    and not last else None
                tau = tau / 2 if jump is None else jump
        if below is not None:
            raise FlowError(f"step {self.k + 1} at t={self.t:.6g} failed: the step size fell to {below:.3g}, below "
                            f"min_tau = {floor:.3g} (the clock would freeze); rejected: " + "; ".join(rejected),
                            step=self.k + 1, t=self.t, rejected=rejected)
        h = self.mesh.with_vertices(self.X).h
        wide = (f" (tau_tilde = {self.tau_tilde:.3g} is {self.tau_tilde / (h * h):.3g} h^2: above about h^2 the step "
                "loses tangential convexity, and the retries halve tau only; docs/theory/tau_tilde.md)"
                if self.tau_tilde > h * h else "")
        raise FlowError(
            f"step {self.k + 1} at t={self.t:.6g} failed after {self.settings.max_retries} retries"
            + (f" with each of {' and '.join(solvers)}" if len(solvers) > 1 else "") + wide + ": "
            + "; ".join(rejected),
            step=self.k + 1, t=self.t, rejected=rejected, hint=self._fixed_step_hint(smallest, rejected),
        )

    def _attempt(self, tau: float, last: bool) -> tuple[np.ndarray, np.ndarray, Any, str | None, dict[str, float]]:
        """One attempt of the step at ``tau`` with the current solver (``last``: the solver's last attempt, which
        runs without the iteration budget) and the post-processing of its solution: redistribution (curves), the
        outer constraints' restoration, the conformal gauge and Y[X].

        While the mesh controls pause at a healthy state at rest (:data:`REST_SPEED`) the attempt is the paper's step,
        without the in-step tangential control. It stands when it is accepted and moves no moving node faster than
        ``REST_SPEED`` or than the step before it (a slide that dies out); otherwise the attempt is made with the
        control, and the pause ends: for the rest of the flow when the paused attempt moved the nodes, for this step
        when it was rejected.

        Returns
        -------
        (X, Y, res, reason, moved): X (N, m) and Y (N, m) the new state, ``res`` the solver's result (None when
        the solver raised), ``reason`` why the attempt is rejected (None: accepted), ``moved`` the statistics of
        the post-processing (history columns).
        """
        if self._paused:
            X, Y, res, reason, moved = self._attempt_with(tau, last, CONTROL_OFF)
            still = reason is None and self._speed(X, self.X, tau) < max(REST_SPEED, self._slide)
            if not still:  # (a rejected attempt ends this pause only: the step with the control may pause again)
                self._paused, self._drifting = False, reason is None
            if still or not self._control.enabled:  # (without an in-step control the attempt would be the same)
                return X, Y, res, reason, moved
        return self._attempt_with(tau, last, ())

    def _attempt_with(self, tau: float, last: bool, off: Collection[str]
                      ) -> tuple[np.ndarray, np.ndarray, Any, str | None, dict[str, float]]:
        """:meth:`_attempt` with the terms ``off`` left out (:meth:`params`)."""
        p = self.params(self.X, tau, off)
        z0 = self.problem.pack_z(self.X, self.Y)
        f0 = self.evaluator.f(z0, p)
        if hasattr(self.solver, "iteration_limit"):
            self.solver.iteration_limit = None if last else self._iteration_limit() or self._first_step_limit()
        if hasattr(self.solver, "guard_allowed"):  # a grown step that needs the guard is retried at the last size
            self.solver.guard_allowed = not self._grown(tau)
        X, Y, moved = self.X, self.Y, {}
        try:
            res = self.solver.solve(z0, p, self.lam_g)
        except RuntimeError as exc:  # CasADi reports evaluation failures as RuntimeError
            return X, Y, None, f"solver error: {str(exc).strip().splitlines()[-1]}", moved
        if not res.converged:
            res = self._from_control_free_step(res, z0, p, tau)
        X, Y = self.problem.unpack_z(res.z, self.X)
        reason = self._reject_reason(res, f0, X)
        if reason is None and self._grown(tau):
            reason = self._crushes(X, (f0 - res.f) / abs(f0) if f0 else 0.0)
        if reason is None and not last:  # (the last attempt is taken: the mesh control repairs it)
            reason = self._collapses(X)
        if reason is None and self.settings.redistribute:
            e_step = self.discrete_energy(X, Y)
            Xr = geometry.redistribute_curve(self.mesh.with_vertices(X))
            moved = {"redistribution_shift": float(np.abs(Xr - X).max()), "energy_before_redistribution": e_step}
            X = Xr
        if reason is None and self.problem.nh:
            moved["constraint_violation_solver"] = self.constraint_violation(X)
            try:
                X = self._restore(X)
            except (RuntimeError, np.linalg.LinAlgError) as exc:
                reason = str(exc)
        fitted = self.settings.conformal_gauge or self._drift_rule  # (the motion fitted from the state, once)
        start = self.mesh.with_vertices(self.X) if fitted else self.mesh
        if reason is None and self.settings.conformal_gauge:
            b, centre, scale = geometry.conformal_motion(start, X)
            Xg = geometry.special_conformal_map(X, -b, centre, scale)
            moved["conformal_gauge_shift"] = float(np.abs(Xg - X).max())
            X = Xg
        if reason is None and self._drift_rule:
            c, share, centre, _ = geometry.conformal_fit(start, X)
            moved["drift_share"] = share
            if share >= DRIFT_SHARE and self.settings.rest_dilation:
                # the drift's dilation, undone: the smooth flow's motion is L^2-orthogonal to the dilation
                X = centre + (X - centre) / (1 + c[6])
                moved["dilation_undone"] = float(c[6])
        if reason is None:
            try:
                Y = self._solve_y(X, tau, Y)
            except (RuntimeError, ValueError, ArithmeticError) as exc:
                reason = f"inner equation Y[X] failed: {exc}"
            else:
                if not np.all(np.isfinite(Y)):
                    reason = "inner equation Y[X] gave non-finite values"
        return X, Y, res, reason, moved

    def _from_control_free_step(self, cold: Any, z0: np.ndarray, p: np.ndarray, tau: float) -> Any:
        """The solve of a first step's attempt at ``tau`` with the tangential control, whose solve from the state
        ``z0`` failed (``cold``), from the solution of the same step without the control (the paper's step,
        :data:`CONTROL_OFF`). The result carries the iterations and solver counts of all the solves; when the step
        without the control fails too, it is ``cold``'s with both statuses. ``cold`` itself without a control, after
        the first step or on a stop request.

        Measured (2026-11-30, ``sphere_cap`` from its flat start, 12 rings, 547 v): the control's term is small
        (1.3e-5 against the step's objective 1.53 at the start, 4.7e-4 against 0.59 at the solution, whose nodes it
        moves by 0.18 h) but positive semi-definite. On IPOPT's path from the state, far from the flow's shape, the
        step's reduced Hessian is indefinite without it (IPOPT regularises it by 10^-1.3 at the 8th iteration and
        takes a damped step of 0.05); with it the Hessian is barely definite there, IPOPT takes the undamped Newton
        step, 0.49 (7 h, mostly tangential), and wanders among near-inverted meshes (NaN constraints at trial
        points, the regularisation up to 10^7.7): 255 iterations without a budget, three cuts by the first step's
        budget of 100 and tau / 8 with it. From the step without the control (13 iterations) it takes 4, to the
        minimiser of the 255 (24 rings: 16 + 4, where the cold start had not taken the step after 300 s). Only after
        a failed solve: where the cold solve converges, that start can land on another minimiser (a clamped
        icosphere(2) cut at z > -0.2 with ``tangential_weight = 1``: W_c 7.19993, lower than the cold solve's
        7.21206, but the smallest angle 22.9 instead of 31.1 degrees after step 1, then a remeshing in every step,
        tests/test_boundary.py). IPOPT's solves only: newton-krylov's failed first attempts on a 1:1:2 ellipsoid
        (trimesh icosphere(5), 10,242 v, the ``file`` problem) failed without the control too, and the same step 1
        (tau / 4 after 2 retries) took 297 s instead of 160.
        """
        if self.k or not self._control.enabled or self.solver.name != "ipopt" or self._stop():
            return cold
        solves = [cold]
        try:
            solves.append(self.solver.solve(z0, self.params(self.X, tau, CONTROL_OFF), self.lam_g))
            if solves[-1].converged:
                solves.append(self.solver.solve(solves[-1].z, p, self.lam_g))
        except RuntimeError:
            pass
        last = solves[-1] if len(solves) == 3 else cold if len(solves) == 1 else dataclasses.replace(
            cold, status=f"{cold.status}, without the control {solves[1].status}")
        return dataclasses.replace(last, iterations=sum(r.iterations for r in solves), stats={
            k: sum(r.stats.get(k, 0) for r in solves) if k.startswith(("n_", "t_wall")) and is_number(v) else v
            for k, v in last.stats.items()})

    def _accept(self, X: np.ndarray, Y: np.ndarray, tau: float, res: Any, moved: dict[str, float], t0: float,
                tries: int, rejected: list[str], spent: int, solver: str | None = None) -> StepResult:
        """Make the attempt's state (X, Y) at ``tau`` the flow's, control its mesh and return the step's result
        (``t0``: the step's start on the perf counter; ``tries``: its retries; ``rejected``: the rejected attempts'
        reasons; ``spent``: the solver iterations of all its attempts; ``solver``: the state's maker when it is not
        the step solver (a Newton step on normal motions), whose iteration count then stays out of the budget's
        median and which leaves the step size as it was)."""
        # (the step to t_end lands on it: t + (t_end - t) was 1 ulp off, a new user's --t-end 1.1 ended at
        # t = 1.0999999999999999)
        t, end = self.t + tau, self._t_end
        if math.isfinite(end) and abs(t - end) <= 1e-12 * max(1.0, abs(end)):  # (run's own test of the end)
            t = end
        self.X, self.Y, self.t, self.k = X, Y, t, self.k + 1
        self.lam_g = res.lam_g
        # (a Newton step leaves the step size: doubled by three of them, a new user's noisy 2,562-v ellipsoid began
        # its next time step at 32 h, which failed five times, 29 s instead of 18.5 s)
        if solver is None and not (self._cut and not tries):  # (a step shortened to land on t_end: the control
            # goes on from the step size it had asked for; it had doubled the short step, and an extended run took
            # extra small steps: a new user's check)
            self._grow_tau(tau, tries)
            if self.solver.name == self.main_solver(self.mesh.n_vertices):  # (another solver's count is no measure)
                self._accepted_iterations = [*self._accepted_iterations[-BUDGET_WINDOW + 1:], res.iterations]
            self._warn_loose_start(res)
        solver_name = solver or self.solver.name
        t_control = time.perf_counter()
        action, mstats = self._control_mesh(tau) if self.remesh else ("", {})
        mstats["t_wall_control"] = time.perf_counter() - t_control
        if self._paused or self._drifting:  # (REST_SPEED; read back by restart)
            mstats["mesh_pause"] = 2 if self._drifting else 1
        if self._paused:
            mstats["mesh_slide"] = self._slide
        result = self._result(self.X, self.Y, tau, res.f, res, time.perf_counter() - t0, tries, rejected)
        drift = moved.get("drift_share", 0.0) >= DRIFT_SHARE
        if self._rest and self._rest_tau_tilde(tries, tau, result.willmore, result.measure, drift):
            # Y, the discrete energy and tau_tilde of the state are those of the halved tau_tilde
            result = self._result(self.X, self.Y, tau, res.f, res, time.perf_counter() - t0, tries, rejected)
        result.rest_steps = self._rest_steps
        result.stats.update(moved)
        result.stats.update(mstats)
        result.stats["rejected_iterations"] = spent - res.iterations
        result.stats["solver"] = solver_name
        result.remeshed = action
        if self.settings.relax:
            self._control_change += self._control_share(result.row())
            # the relax test: over the last RELAX_WINDOW steps without smoothing or remeshing, the Willmore
            # energy changed by less than relax_tol relative per nominal step, or rose without a flip
            value = self._watched(result)
            result.relaxed = self.relaxed = self._relax_test(value, tau, action, solver_name == NEWTON_SOLVER)
            if self.relaxed and self._checks_saddles():
                lowest = self._stability_at_rest()
                result.stats.update(stability=lowest, stability_gap=self.last_gap)
                e_rest, gap_rest, moved = result.energy, self.last_gap, ""
                if self._go_on(lowest, self.last_gap):  # not at rest: the relaxation goes on (MAX_GO_ON)
                    result.relaxed = self.relaxed = False
                elif lowest < -SADDLE_TOL:
                    moved = "saddle" if self._kicks < MAX_SADDLE_KICKS and self._leave_saddle(tau) else ""
                elif self._polish(tau):
                    moved = "polish"
                if moved:
                    new = self._result(self.X, self.Y, tau, res.f, res, time.perf_counter() - t0, tries, rejected)
                    new.stats, new.rest_steps = result.stats, result.rest_steps
                    # (the before values stay the stepped state's when the mesh control acted: the step's energy
                    # inequality reads them; the after value is the state's after every action of the row)
                    for k, v in (("energy_before_remesh", e_rest), ("willmore_before_remesh", result.willmore),
                                 ("min_angle_before_remesh", result.quality["min_angle"])):
                        new.stats.setdefault(k, v)
                    new.stats.update(energy_after_remesh=new.energy, stability=self.last_stability,
                                     stability_gap=self.last_gap, energy_before_move=e_rest,
                                     willmore_before_move=result.willmore, stability_gap_before_move=gap_rest)
                    new.remeshed = "+".join([*filter(None, [action]), moved])
                    value = self._watched(new)
                    if moved == "saddle":  # (the window restarts from the state off the saddle)
                        new.relaxed = self.relaxed = self._relax_test(value, tau, new.remeshed,
                                                                      solver_name == NEWTON_SOLVER)
                    else:  # (the window ends at the polished state, as a restart replays it)
                        self._relax_window[-1] = (value, *self._relax_window[-1][1:])
                        new.relaxed = True
                    result = new
        return result

    def _warn_loose_start(self, res: SolveResult) -> None:
        """Warn (once per flow) when the step solver accepted a step at its start, in 0 iterations, only because its
        ``tol`` is looser than its default: X did not move where the default test would have moved it (a new user's
        64-gon circle: newton-krylov at ``tol = 1e-2`` and lbfgs at ``1e-1`` took 11 such steps, R(0.1) = 1.000000
        against the exact 1.046635). The solvers that report their test (``kkt_residual`` <= ``gtol``, where ``gtol``
        is ``tol`` times the step's scale) are judged; a state at rest, whose residual passes the default test too,
        is not warned of."""
        tol, residual, gtol = getattr(self.solver, "tol", None), res.stats.get("kkt_residual"), res.stats.get("gtol")
        if self._start_warned or res.iterations or None in (tol, residual, gtol):
            return
        default = solver_settings(self.solver.name).defaults()["tol"]
        if residual > gtol * default / tol:
            self._start_warned = True
            warnings.warn(LooseToleranceWarning(
                f"step {self.k}: solver {self.solver.name} accepted the step at its start (0 iterations, X did not "
                f"move) because tol = {tol:g} is loose: its residual {residual:.2e} is above what the default tol = "
                f"{default:g} accepts; lower tol (--set tol=...) for a flow that moves"), stacklevel=4)

    def _go_on(self, lowest: float, gap: float) -> bool:
        """Whether an ended relax window whose state has the lowest eigenvalue ``lowest`` and the gap ``gap`` on
        normal motions is gone past (:data:`MAX_GO_ON`): then the window restarts from that state."""
        if not (_off_rest(lowest, gap) and self._go_ons < MAX_GO_ON):
            return False
        self._go_ons += 1
        self._relax_window = self._relax_window[-1:]
        self.relax_reason = ""
        return True

    def _spectrum_fits(self) -> bool:
        """Whether :meth:`stability` takes the current mesh: a surface in R^3 of at most
        :data:`STABILITY_MAX_VERTICES` vertices (the relaxation's test for a saddle, its Newton steps)."""
        return self.mesh.d == 2 and self.mesh.m == 3 and self.mesh.n_vertices <= STABILITY_MAX_VERTICES

    def _checks_saddles(self) -> bool:
        """Whether an ended relaxation tests its state for a saddle (``relax_check``, :meth:`_spectrum_fits`)."""
        return self.settings.relax_check and self._spectrum_fits()

    def _stability_at_rest(self) -> float:
        """The lowest eigenvalue of :meth:`stability` at the relaxed state (kept with its mode for the move off a
        saddle)."""
        try:
            st = self.stability(1)
        except ArithmeticError as err:  # (the iterative eigensolver's or CG's failure: the state is not tested)
            self.untested, self.last_stability, self.last_gap = str(err), float("nan"), float("nan")
            return self.last_stability
        self._saddle_mode, self._newton = st.modes[0], st.newton
        self.last_stability, self.last_gap, self.untested = float(st.eigenvalues[0]), st.gap, ""
        return self.last_stability

    def _spectrum_solver(self) -> Any:
        """The reduced solver whose factorisations serve :meth:`stability` in a flow whose step solver is not one
        (IPOPT): ``newton-krylov``'s Cholesky of the N x N block of J_Y, kept for the step problem (its symbolic
        analysis is once per pattern), where the flow's own Y[X] solves stay as they were. At 2,562 vertices a Newton
        step on normal motions took 0.21 s with the sparse LU of the whole J_Y (None: ``normal_spectrum``'s
        default) and 0.13 s with it. None where ``newton-krylov`` cannot take the problem."""
        if self._spectral is None or self._spectral.ev is not self.evaluator:
            saved = self.evaluator.cholesky
            try:
                self._spectral = make_solver("newton-krylov", self.evaluator)
            except (ValueError, UserInputError):
                return None
            finally:
                self.evaluator.cholesky = saved  # (newton-krylov's constructor gives the evaluator its backend)
        return self._spectral

    def _newton_relax_step(self, tau: float, t0: float) -> StepResult | None:
        """A relaxation's step by Newton on normal motions (``relax_newton``): the step of :meth:`stability` (its
        quadratic model's minimum), at most :data:`RELAX_NEWTON_CAP` h long, halved until the energy falls and the
        mesh stays above the repair thresholds (onto the outer constraints), then accepted as a step of size ``tau``
        (the mesh control and the relax test follow as for a time step); None where there is no such step (the
        Hessian on normal motions not positive definite, or no trial lowered the energy): the time step then."""
        try:
            st = self._normal_spectrum(0, "auto")
        except ArithmeticError:
            return None
        d = st.newton
        if not (np.all(np.isfinite(d)) and np.abs(d).max() > 0):
            return None
        trial = self._halved_move(d, RELAX_NEWTON_CAP * self.mesh.with_vertices(self.X).h, tau, 8, healthy=True)
        if trial is None:
            return None
        _, X, Y, a = trial
        z = self.problem.pack_z(X, Y)
        res = SolveResult(z=z, f=float(self.evaluator.f(z, self.params(self.X, tau))), lam_g=None, converged=True,
                          status="Newton step on normal motions", iterations=1,
                          stats={"stability_gap_before_move": st.gap, "newton_fraction": a})
        return self._accept(X, Y, tau, res, {}, t0, 0, [], 1, solver=NEWTON_SOLVER)

    def _halved_move(self, d: np.ndarray, longest: float, tau: float, tries: int,
                     healthy: bool = False) -> tuple[float, np.ndarray, np.ndarray, float] | None:
        """The move by a ``d`` ((N, m)), a = min(1, ``longest`` / max |d|) halved until the energy falls (and, with
        ``healthy``, the mesh stays above the repair thresholds), at most ``tries`` trials, onto the outer constraints
        (:meth:`_trial_move`): (e, X', Y[X'], a), or None. A polishing step's and a relaxation's Newton step's."""
        e0, a = self.discrete_energy(self.X, self.Y), min(1.0, longest / float(np.abs(d).max()))
        for _ in range(tries):
            trial = self._trial_move(a * d, tau)
            if trial is not None and trial[0] < e0 and not (healthy and self._needs_repair(trial[1],
                                                                                           self.mesh.simplices)):
                return (*trial, a)
            a /= 2
        return None

    def _polish(self, tau: float) -> bool:
        """Newton steps on normal motions from a relaxed minimum (``relax_check``; :meth:`stability`'s ``newton``):
        while the gap is above :data:`POLISH_GAP` and not above :data:`POLISH_MAX_GAP`, at most :data:`POLISH_STEPS`,
        each at most :data:`POLISH_CAP` h long and halved until it lowers the energy (onto the outer constraints),
        kept when it shrinks the gap and leaves the mesh above the repair thresholds; True when the state moved. The
        shape then rests on normal motions at the mesh's tangential distribution, which the relaxation's step/repair
        exchange leaves above it (a 934-vertex trimesh torus: gap 1.6e-3 -> 1.6e-6 -> 4.7e-10 -> 1.9e-13)."""
        h, moved = self.mesh.with_vertices(self.X).h, False
        for _ in range(POLISH_STEPS):
            if not POLISH_GAP < self.last_gap <= POLISH_MAX_GAP:  # (nan: no minimum of the model)
                break
            best = self._halved_move(self._newton, POLISH_CAP * h, tau, 6)
            if best is None:
                break
            kept = (self.X, self.Y, self._saddle_mode, self._newton, self.last_stability, self.last_gap)
            self.X, self.Y, self.lam_g = best[1], best[2], None
            self._stability_at_rest()
            # a Newton step from rest shrinks the gap and keeps the mesh above the repair thresholds; one that does
            # not is undone and ends the polish
            if not self.last_gap < kept[5] or self._needs_repair(self.X, self.mesh.simplices):
                self.X, self.Y, self._saddle_mode, self._newton, self.last_stability, self.last_gap = kept
                self.untested = ""
                break
            self._X_prev, moved = self.X, True
        return moved

    def _trial_move(self, d: np.ndarray, tau: float) -> tuple[float, np.ndarray, np.ndarray] | None:
        """(e, X', Y[X']) of the state moved by ``d`` ((N, m)) onto the outer constraints; None when the restoration or
        Y[X'] fails or e is not finite."""
        try:
            X1 = self._restore(self.X + d)
            Y1 = self._solve_y(X1, tau)
        except (RuntimeError, ArithmeticError):
            return None
        e1 = self.discrete_energy(X1, Y1)
        return (e1, X1, Y1) if np.isfinite(e1) else None

    def _leave_saddle(self, tau: float) -> bool:
        """Move the state along the mode of its negative eigenvalue (:meth:`_stability_at_rest`), onto the outer
        constraints, by the move of the lowest energy among +-1, 1/2, 1/4 and 1/8 times ``SADDLE_KICK`` h at most (the
        energy along the mode is a quartic: on the c0 = 0.8 vesicle it is lowest near h / 4); False (the state kept)
        when none lowers it."""
        h = self.mesh.with_vertices(self.X).h
        e0, best = self.discrete_energy(self.X, self.Y), None
        for move in SADDLE_KICK * h * np.array([1.0, -1.0, 0.5, -0.5, 0.25, -0.25, 0.125, -0.125]):
            trial = self._trial_move(move * self._saddle_mode, tau)
            if trial is not None and trial[0] < e0 and (best is None or trial[0] < best[0]):
                best = trial
        if best is None:
            return False
        self.X, self.Y, self.lam_g = best[1], best[2], None
        self._X_prev = self.X
        return True

    def _iteration_limit(self) -> int | None:
        """Iteration budget of the next attempt: ``max(iteration_budget_min, iteration_budget x median)``.

        None (no budget) before the first accepted step: there is nothing to compare with (the first
        step of the 2,562-vertex ellipsoid needs 63 iterations and converges); :meth:`_first_step_limit`
        applies there.
        """
        if self.settings.iteration_budget == 0 or not self._accepted_iterations:
            return None
        med = float(np.median(self._accepted_iterations))
        return max(self.settings.iteration_budget_min, int(np.ceil(self.settings.iteration_budget * med)))

    def _first_step_limit(self) -> int | None:
        """Iteration budget of the attempts of a step with no median to compare with: ``first_step_budget`` (None
        when 0, once the main solver has accepted a step, or when ``iteration_budget = 0`` turns every budget off, as
        the reproduction's paper scheme does). That is the first step, and a later one when no step so far was a
        time step of the main solver: after Newton steps of a relaxation only, or after steps of the fallback solver.

        The first step of a noisy input can be far harder than the rest (the noisy capsule of
        ``reports/mesh_quality_study.py``: 200 iterations at tau, tau/2 and tau/4, then 16 at tau/8),
        while first steps that converge take 3-63 iterations on the measured meshes. A new user's relaxation of
        the double torus of docs/guide/defaults_measured.md (839 v) took 27 Newton steps, then its step 28 failed
        9 newton-krylov attempts and 8 of the IPOPT fallback's, each of these 200 iterations with no budget
        (385 s for the step).
        """
        if self._accepted_iterations or self.settings.iteration_budget == 0:
            return None
        return self.settings.first_step_budget or None

    # -- mesh control ------------------------------------------------------------------
    def _patch_quality(self, X: np.ndarray, F: np.ndarray, free: np.ndarray | None,
                       graded: bool | None = None) -> dict[str, float]:
        """:func:`geometry.triangle_quality` of the triangles with a free vertex (all without boundary); the edge ratio
        within each triangle when ``graded`` (default: once the mesh is graded, :meth:`_graded`)."""
        return geometry.triangle_quality(X, F if free is None else F[free[F].any(axis=1)],
                                         self._graded() if graded is None else graded)

    def _local(self) -> bool:
        """Whether refinements are local (``refine_local``)."""
        return self.settings.refine_local

    def _graded(self) -> bool:
        """Whether the mesh was refined locally: its resolution then varies on purpose, so the threshold remeshing is
        local too (:meth:`_local_patch`) and the edge-ratio threshold applies within each triangle."""
        return self._refinements > 0 and self._local()

    def _local_patch(self, X: np.ndarray, F: np.ndarray, start: np.ndarray, factor: float = 1.0
                     ) -> tuple[float, np.ndarray]:
        """(target edge, (N,) bool region) of a local remeshing of (X, F): the vertices ``start`` grown by
        :data:`LOCAL_RINGS` rings of triangles, toward the equilateral edge of the triangles at ``start`` divided by
        ``factor`` (the resolution there: the region's own mean would coarsen a finer part of a graded mesh)."""
        from willmore_nlp import remesh as rm

        region = np.zeros(X.shape[0], bool)
        region[start] = True
        target = rm.equilateral_edge(X, F, region) / factor
        for _ in range(LOCAL_RINGS):
            region[F[region[F].any(axis=1)]] = True
        return target, region

    def _below_thresholds(self, q: dict[str, float], margin: float = 0.0) -> bool:
        """Patch quality ``q`` with an angle below ``remesh_min_angle + margin`` or an edge ratio above
        ``remesh_max_edge_ratio``."""
        return (q["min_angle"] < self.settings.remesh_min_angle + margin
                or q["edge_ratio"] > self.settings.remesh_max_edge_ratio)

    def _needs_repair(self, X: np.ndarray, F: np.ndarray, margin: float = 0.0) -> bool:
        """:meth:`_below_thresholds` of the patch of (X, F)."""
        return self._below_thresholds(self._patch_quality(X, F, self.free), margin)

    def _speed(self, X: np.ndarray, Xk: np.ndarray, tau: float, normal: bool = False) -> float:
        """Largest motion of a moving node in the step of size tau from Xk to X (``normal``: along its vertex normal
        at Xk), in L per unit of the surface's own time L^4 (L: :func:`geometry.length_scale` of X's area)."""
        D = X - Xk
        if normal:
            D = np.einsum("ij,ij->i", D, geometry.vertex_normals(self.mesh.with_vertices(Xk)))[:, None]
        moved = np.linalg.norm(D if self.free is None else D[self.free], axis=1)
        L = geometry.length_scale(geometry.measure(self.mesh, X), 2, self.mesh.is_closed)
        return float(moved.max()) * L**3 / tau

    def _pauses(self, X: np.ndarray, Xk: np.ndarray | None, tau: float, needs: bool) -> bool:
        """Whether the mesh controls pause after the step of size tau from Xk to X (:data:`REST_SPEED`): the light
        repair after it and the in-step tangential control of the next steps (:meth:`_attempt`).

        They pause on a clamped or open surface when the patch is not below the thresholds (``needs``) and the state
        is at rest: a paused step stood (:meth:`_attempt`), or a step with the controls moved no moving node along its
        vertex normal faster than ``REST_SPEED``. Never before a first step (Xk None) or once a paused step moved the
        nodes too fast, nor on closed surfaces, which the paper's scheme does not hold at rest (its O(tau_tilde)
        drift, met by ``rest_tau_tilde`` and ``rest_dilation``). The history column ``mesh_pause`` records the outcome
        (1 paused, 2 ended for good) and ``mesh_slide`` the speed of the step, which the next (paused) step may reach,
        for :meth:`restart`.
        """
        rest = Xk is not None and not self._drifting and (self.boundary is not None or not self.mesh.is_closed) and (
            self._paused or self._speed(X, Xk, tau, normal=True) < REST_SPEED)
        self._paused = rest and not needs
        if self._paused:  # (Xk is not None)
            self._slide = self._speed(X, Xk, tau)
        return self._paused

    def _control_mesh(self, tau: float) -> tuple[str, dict[str, float]]:
        """Repair the mesh of the accepted state when its quality dropped (see ``remesh``).

        Tries, in order, Delaunay flips, tangential smoothing projected onto the surface (with
        flips again) and isotropic remeshing, and stops at the first result that meets the
        thresholds. Rebuilds the step NLP when the connectivity changed and solves Y[X] again.
        Returns the actions taken ("" when none) and the energies before and after.
        """
        from willmore_nlp import remesh as rm

        X, F = self.X, self.mesh.simplices
        moved = np.linalg.norm(X - self._X_prev, axis=1) if self._X_prev.shape == X.shape else None
        # the step's fall of the smallest patch angle: the isotropic remeshing comes when the next step at that
        # rate would take the mesh below remesh_min_angle, so that stepped states stay above it too
        q0 = self._patch_quality(X, F, self.free)
        drop = 0.0 if moved is None else max(0.0, self._patch_quality(self._X_prev, F, self.free)["min_angle"]
                                             - q0["min_angle"])
        Xk = None if moved is None else self._X_prev
        refine = self._refines(X, F, Xk)
        # the global refinement's target edge is the stepped state's (a local one has its own)
        target = self._remesh_target(X, F, self.free) / REFINE_FACTOR if refine and not self._local() else None
        self._X_prev = X
        repair = self.settings.remesh_repair > 0
        needs = self._below_thresholds(q0)
        # the light repair moves each vertex by at most REPAIR_SPEED times what the step moved it: the mesh
        # follows the surface at its own speed, and a state that the flow does not move (an equilibrium)
        # is left alone, so the fixed points are those of the paper's scheme
        # (and none at a healthy state at rest, whose in-step control pauses too: REST_SPEED)
        light = not self._pauses(X, Xk, tau, needs) and repair and moved is not None and bool(moved.max() > 0)
        if not light and not needs and not refine:
            return "", {}
        free = self.free
        actions: list[str] = []
        boundary = self.boundary

        def lumped(Xc: np.ndarray, Fc: np.ndarray) -> float:  # (flips keep the boundary: no new Mesh to check)
            return geometry.willmore_energy(self.mesh, self.energy_nodes, vertices=Xc, simplices=Fc)

        rest: list[bool] = []  # (computed once, when a flip is first proposed)

        def near_rest() -> bool:  # the step changed the lumped W by at most flip_rest of it
            if not rest:
                w0 = None if Xk is None or not self.settings.flip_rest else lumped(Xk, F)
                rest.append(w0 is not None and abs(lumped(X, F) - w0) <= self.settings.flip_rest * abs(w0))
            return rest[0]

        def flip(Xc: np.ndarray, Fc: np.ndarray) -> tuple[np.ndarray, int]:
            """Delaunay flips; on a healthy patch near rest only those that do not raise the lumped W by FLIP_RISE."""
            Fn, k = rm.delaunay_flips(Xc, Fc, free)
            if k and not needs and near_rest():
                w0, w1 = lumped(Xc, Fc), lumped(Xc, Fn)
                if w1 > w0 + FLIP_RISE * abs(w0):
                    return Fc, 0
            return Fn, k

        F1, flips = flip(X, F)
        X1 = X
        if light:
            # remesh_repair passes after every step; up to REPAIR_ROUNDS times as many while the mesh is
            # below the thresholds, before the stronger repairs (which move the shape by O(h^2))
            for _ in range(REPAIR_ROUNDS):
                Xr = rm.tangential_relax(X1, F1, free, iterations=self.settings.remesh_repair, cap=REPAIR_SPEED * moved)
                Fr, n = flip(Xr, F1)
                if _sharpens(X, F, Xr, Fr, self.settings.max_dihedral):  # a round that folds the surface: stop
                    # before it, so that a remeshing starts from the last state without the fold (a thin torus's
                    # slivers: the rounds folded it to 179 deg, its remeshing was folded too and the fold check
                    # dropped every repair; tests/test_folds.py)
                    break
                X1, F1 = Xr, Fr
                flips += n
                if not self._needs_repair(X1, F1):
                    break
        if flips:
            actions.append("flips")
        if light:
            actions.append("repair")
        if not repair and self._needs_repair(X1, F1):  # the repair passes replace the polyhedral smoothing
            X1 = rm.tangential_smooth(X1, F1, free)
            F1, _ = rm.delaunay_flips(X1, F1, free)
            actions.append("smooth")
        light_only = (X1, F1, boundary, list(actions)) if light else None  # (the fallback when a remeshing fails)
        if self._needs_repair(X1, F1, drop) and not _explicit(boundary):
            # a graded mesh keeps its resolution: only the triangles below the threshold and LOCAL_RINGS around them
            bad = F1[geometry.min_angles(X1, F1) < self.settings.remesh_min_angle + drop] if self._graded() else None
            remeshed = (None if bad is not None and not bad.size else self._isotropic_remesh(
                X1, F1, boundary, local=None if bad is None else self._local_patch(X1, F1, bad)))
            if remeshed is not None:
                X1, F1, boundary = remeshed
                actions.append("remesh")
        refine = refine or (self._local() and self._refines(X, F, Xk, (X1, F1)))
        if refine:  # kept when it resolves the sharpest edge better than the state it refines
            local = None
            if self._local():  # the region of the edges sharper than LOCAL_REFINE_ANGLE refine_dihedral
                turn, ends = _movable_turns(X1, F1, _free_of(boundary))
                sharp = ends[turn > LOCAL_REFINE_ANGLE * self.settings.refine_dihedral]
                local = self._local_patch(X1, F1, sharp, REFINE_FACTOR) if sharp.size else None
            else:  # (the global refinement compares with the stepped state)
                turn = _movable_turns(X, F, free)[0]
            # (none when the repair left no movable edge that sharp: a clamped cylinder's stepped state had one)
            refined = (self._isotropic_remesh(X1, F1, boundary, retarget=True, target=target, local=local)
                       if local is not None or not self._local() else None)
            if refined is not None and _movable_turns(*refined[:2], _free_of(refined[2]))[0].max() < turn.max():
                X1, F1, boundary = refined
                actions.append("refine")
        if not actions:
            return "", {}
        q1 = self._patch_quality(X1, F1, _free_of(boundary))
        if not light and "refine" not in actions and not _improves(q0, q1):
            return "", {}  # no improvement: keep the flow's own mesh rather than churn
        if _sharpens(X, F, X1, F1, self.settings.max_dihedral):
            return "", {}  # the stepped state passed the fold check; a repair across a crease must not fold it
        e_before = self.discrete_energy(X, self.Y)
        w_before = geometry.willmore_energy(self.mesh.with_vertices(X), self.energy_nodes)
        angle_before = geometry.triangle_quality(X, F)["min_angle"]
        old = (self.mesh, self.boundary, self.tau_tilde)
        h_old = self.mesh.with_vertices(X).h if "refine" in actions else float("nan")  # (for the refinement only)
        # tau_tilde ~ h^2 of the finest part (a local refinement: its region's)
        fine = 1.0 / REFINE_FACTOR**2 if "refine" in actions and self._local() else None
        if F1.shape != F.shape or not np.array_equal(F1, F):
            self._build(Mesh(X1, F1, self.mesh.source), boundary)
        if "refine" in actions and self.settings.steps_from_h in ("tau_tilde", "both"):
            self.tau_tilde *= (self.mesh.h / h_old) ** 2 if fine is None else fine
        try:
            X1, Y1 = self._restored(X, X1, tau, not {"remesh", "refine"} & set(actions))
        except (RuntimeError, ValueError, ArithmeticError) as exc:
            self.tau_tilde = old[2]
            # a remeshing or refinement that the outer constraints cannot take: the light repair alone (a 642-vertex
            # vesicle cup of v = 0.5 went without any repair from step 24 on, each remeshing of its forming neck
            # needing a restoration that moved a vertex by 0.41-0.49 h, and failed at step 94; 2026-12-01)
            fallback = light_only is not None and {"remesh", "refine"} & set(actions)
            try:
                if not fallback:
                    raise exc
                X1, F1, boundary, actions = light_only
                if F1.shape != F.shape or not np.array_equal(F1, F):  # (its flips: built once, not the old first)
                    self._build(Mesh(X1, F1, self.mesh.source), boundary)
                elif self.mesh is not old[0]:
                    self._build(*old[:2])
                X1, Y1 = self._restored(X, X1, tau, True)
            except (RuntimeError, ValueError, ArithmeticError) as last:
                warnings.warn(f"step {self.k}: mesh repair dropped on the new mesh ({last})", stacklevel=3)
                if self.mesh is not old[0]:
                    self._build(*old[:2])
                return "", {}
        if "refine" in actions:
            self._refinements += 1
            self._refined_at, self._tau_c = self.k, None  # (convex_start: the next step is on a new discretisation)
            where = (f"near its sharp edges, {old[0].n_vertices} -> {self.mesh.n_vertices} vertices, edge there / "
                     f"{REFINE_FACTOR:.3g}" if fine is not None else
                     f"{old[0].n_vertices} -> {self.mesh.n_vertices} vertices, mean edge {h_old:.3g} -> "
                     f"{self.mesh.h:.3g}")
            warnings.warn(f"step {self.k}: the mesh was refined ({where}): the normals of adjacent triangles turned by "
                          f"more than refine_dihedral = {self.settings.refine_dihedral:g} deg", stacklevel=3)
        self.X, self.Y, self.lam_g = X1, Y1, None
        self._X_prev = X1
        return "+".join(actions), {"energy_before_remesh": e_before,
                                   "energy_after_remesh": self.discrete_energy(X1, Y1),
                                   "min_angle_before_remesh": angle_before, "willmore_before_remesh": w_before}

    def _refines(self, X: np.ndarray, F: np.ndarray, Xk: np.ndarray | None,
                 repaired: tuple[np.ndarray, np.ndarray] | None = None) -> bool:
        """Whether to refine the surface (X, F) in R^3: the step from the positions Xk of the same vertices (None: no
        step) left an edge whose triangles' normals turn by more than ``refine_dihedral`` and by more than at Xk (a
        feature sharpening past what the mesh resolves: a bar or tube a few edges round; a crease of the input that
        the flow softens is left alone), and a global refinement (toward the current target edge,
        :meth:`_remesh_target`, divided by :data:`REFINE_FACTOR`) would stay within ``refine_max_vertices``.
        ``repaired``: the state (X', F') the repairs made of (X, F) is tested instead, its sharpest edge against
        ``refine_dihedral`` and the sharpest at Xk (on a graded mesh the light repair can sharpen a crease past the
        limit, 71 -> 91 degrees in five steps of a genus-2 flow, where no step did)."""
        s = self.settings
        if (Xk is None or self.mesh.d != 2 or self.mesh.m != 3 or s.refine_dihedral >= 180
                or _explicit(self.boundary) or REFINE_FACTOR**2 * len(X) > s.refine_max_vertices):
            return False
        if repaired is None:
            return _sharp_edges(X, F, s.refine_dihedral, Xk) is not None
        return _sharpens(Xk, F, *repaired, s.refine_dihedral)

    def _remesh_target(self, X: np.ndarray, F: np.ndarray, free: np.ndarray | None) -> float:
        """Target edge of an isotropic remeshing of (X, F): ``remesh_target`` divided by :data:`REFINE_FACTOR` once per
        refinement so far, or (unset) the equilateral edge of the patch, which keeps the current resolution."""
        from willmore_nlp import remesh as rm

        if self.settings.remesh_target:
            return self.settings.remesh_target / REFINE_FACTOR**self._refinements
        return rm.equilateral_edge(X, F, free)

    def _isotropic_remesh(self, X: np.ndarray, F: np.ndarray, boundary: Any, smooth: bool = True,
                          quality: dict[str, float] | None = None, retarget: bool = False,
                          target: float | None = None, local: tuple[float, np.ndarray] | None = None
                          ) -> tuple[np.ndarray, np.ndarray, Any] | None:
        """(X', F', boundary') of an isotropic remeshing of (X, F) toward ``remesh_target`` (default: the equilateral
        edge) followed by flips, or None when it failed (a warning) or did not keep the smallest patch angle and
        improve it or the edge ratio (``retarget``, a resolution the user asks for: when it is below the repair
        thresholds without improving on (X, F)). ``smooth``: :func:`willmore_nlp.remesh.isotropic_remesh`;
        ``quality``: the patch quality of (X, F) when the caller has it; ``local``: (target, region)
        of :meth:`_local_patch`, remeshed alone with its rim fixed (on a clamped surface its free vertices alone)."""
        from willmore_nlp import remesh as rm

        free = _free_of(boundary)
        moved = free
        if local is not None:  # the region alone (of a clamped surface: its free vertices)
            target, moved = local[0], local[1] if free is None else local[1] & free
        try:
            r = rm.isotropic_remesh(X, F, target or self._remesh_target(X, F, free), moved, smooth=smooth)
        except rm.RemeshError as exc:
            warnings.warn(f"step {self.k}: isotropic remeshing skipped ({exc})", stacklevel=4)
            return None
        boundary = None if boundary is None else rm.carry_boundary(boundary, r)
        free2 = _free_of(boundary)
        F2, _ = rm.delaunay_flips(r.vertices, r.simplices, free2)
        graded = self._graded() or local is not None
        qa = self._patch_quality(X, F, free, graded) if quality is None else quality
        qb = self._patch_quality(r.vertices, F2, free2, graded)
        # only a remeshing that keeps the smallest angle and improves it or the edge ratio (with the
        # light repair on, any result was taken: 0.6 deg on a coarse genus-2 flow, mesh_quality.md)
        kept = (not self._below_thresholds(qb) or _improves(qa, qb)) if retarget else (
            qb["min_angle"] >= qa["min_angle"] and _improves(qa, qb))
        if kept and local is not None and not retarget:  # a local repair must not unresolve a sharp part
            kept = not _sharpens(X, F, r.vertices, F2, self.settings.refine_dihedral)
        if not kept:
            return None
        return r.vertices, F2, boundary

    def _repair_input(self, mesh: Mesh, boundary: Any) -> tuple[Mesh, Any]:
        """``input_repair``: the initial mesh and boundary, repaired when the patch is below the repair thresholds
        (Delaunay flips, then an isotropic remeshing with the new vertices on the input's triangles), or remeshed
        toward a ``remesh_target`` that differs from the input's equilateral edge by more than
        :data:`TARGET_CHANGE` (:meth:`_remesh_input`); a warning names what was done. Unchanged when nothing
        improved the smallest angle or the edge ratio."""
        from willmore_nlp import remesh as rm

        free = _free_of(boundary)
        if _explicit(boundary) or (free is not None and not free.any()):  # (no patch: the boundary's own error)
            return mesh, boundary
        X, F = mesh.vertices, mesh.simplices
        q0 = self._patch_quality(X, F, free)
        target = self.settings.remesh_target
        edge = None if target is None else rm.equilateral_edge(X, F, free)
        if edge is not None and abs(np.log(target / edge)) > np.log(1 + TARGET_CHANGE):
            estimate = len(X) * (edge / target) ** 2
            if estimate > max(self.settings.refine_max_vertices, len(X)):  # (a typo would remesh for hours)
                raise UserInputError(
                    f"{mesh.source}: remesh_target = {target:g} would remesh the input ({len(X)} vertices, equilateral "
                    f"edge {edge:.3g}) to about {estimate:,.0f} vertices, more than "
                    f"refine_max_vertices = {self.settings.refine_max_vertices:,}: choose a larger remesh_target or "
                    "raise refine_max_vertices")
            return self._remesh_input(mesh, boundary, target, q0)
        if not self._below_thresholds(q0):
            return mesh, boundary
        F1, n = rm.delaunay_flips(X, F, free)
        actions = ["flips"] if n else []
        X1, b1 = X, boundary
        q = self._patch_quality(X1, F1, free)
        if self._below_thresholds(q):
            remeshed = self._isotropic_remesh(X1, F1, boundary, smooth=False, quality=q)
            if remeshed is not None:
                X1, F1, b1 = remeshed
                actions.append("remesh")
        q1 = self._patch_quality(X1, F1, _free_of(b1))
        if not actions or not _improves(q0, q1):
            warnings.warn(f"{mesh.source}: the input mesh is below the mesh control's thresholds (smallest angle "
                          f"{q0['min_angle']:.3g} deg, edge ratio {q0['edge_ratio']:.3g}) and neither flips nor an "
                          "isotropic remeshing improved it: it is flowed as given", stacklevel=3)
            return mesh, boundary
        _check_shape_kept(mesh, X1, F1, "repairing it at its own edge length")
        new = Mesh(X1, F1, mesh.source)
        self.input_repair = "+".join(actions)
        self._input_min_angle = q0["min_angle"]
        patch = "" if b1 is None or b1.free.all() else " of its moving patch"  # (a clamped strip keeps its own)
        warnings.warn(InputRepairWarning(
            f"{mesh.source}: the input mesh is below the mesh control's thresholds (smallest angle{patch} "
            f"{q0['min_angle']:.3g} deg, edge ratio {q0['edge_ratio']:.3g}); repaired before the first step by "
            f"{' and '.join(actions)}: {mesh.n_vertices} -> {new.n_vertices} vertices, smallest angle{patch} "
            f"{q1['min_angle']:.3g} deg, edge ratio {q1['edge_ratio']:.3g} (input_repair=false flows it as given)"),
            stacklevel=3)
        return new, b1

    def _remesh_input(self, mesh: Mesh, boundary: Any, target: float,
                      q0: dict[str, float]) -> tuple[Mesh, Any]:
        """``input_repair`` of an input whose resolution the user changes (``remesh_target``): an isotropic
        remeshing toward ``target`` (new vertices on the input's triangles) and Delaunay flips, taken unless the
        result is below the repair thresholds without improving on the input (patch quality ``q0``)."""
        remeshed = self._isotropic_remesh(mesh.vertices, mesh.simplices, boundary, smooth=False, quality=q0,
                                          retarget=True)
        if remeshed is None:
            warnings.warn(f"{mesh.source}: remeshing the input toward remesh_target = {target:g} gave no mesh within "
                          "the repair thresholds: it is flowed as given", stacklevel=4)
            return mesh, boundary
        X1, F1, b1 = remeshed
        _check_shape_kept(mesh, X1, F1, f"remeshing it toward remesh_target = {target:g}")
        q1 = self._patch_quality(X1, F1, _free_of(b1))
        new = Mesh(X1, F1, mesh.source)
        self.input_repair = "remesh"
        self._input_min_angle = q0["min_angle"]
        warnings.warn(InputRepairWarning(
            f"{mesh.source}: remeshed toward remesh_target = {target:g} before the first step: {mesh.n_vertices} -> "
            f"{new.n_vertices} vertices, smallest angle {q1['min_angle']:.3g} deg, edge ratio {q1['edge_ratio']:.3g} "
            "(input_repair=false flows it as given)"), stacklevel=4)
        return new, b1

    def _step_scales(self, mesh: Mesh) -> None:
        """What depends on the mean edge h of the mesh the flow runs on (``mesh``, after ``input_repair``): tau and
        tau_tilde named by ``steps_from_h`` rescaled from the input's h (tau ~ h, tau_tilde ~ h^2; a warning says
        so), the floor ``min_tau`` (0.01 h^4 unless given), ``relax_max_tau`` (100 tau unless given), and a warning
        when tau_tilde exceeds about h^2."""
        s = self.settings
        h = mesh.h
        ratio = h / self.initial_mesh.h
        if ratio != 1.0 and s.steps_from_h != "none":
            old = (self.tau, self.tau_tilde)
            if s.steps_from_h in ("tau", "both"):
                self.tau *= ratio
            if s.steps_from_h in ("tau_tilde", "both"):
                self.tau_tilde *= ratio * ratio
            warnings.warn(f"{mesh.source}: the step sizes chosen from the input's mean edge follow the repaired "
                          f"mesh's (h {self.initial_mesh.h:.4g} -> {h:.4g}): tau {old[0]:.4g} -> {self.tau:.4g}, "
                          f"tau_tilde {old[1]:.4g} -> {self.tau_tilde:.4g} (steps_from_h = {s.steps_from_h!r})",
                          stacklevel=3)
        scale, what = 1.0, ""  # (an anisotropy of scale s acts as the inner step tau_tilde s: ANISOTROPY_INNER_MAX)
        an = self._anisotropy
        if an is not None:
            scale, what = an.scale, (f" x the scale {an.scale:.3g} of anisotropy {an.name} (its largest gamma(n) on "
                                     "unit normals; gamma -> s gamma is tau_tilde -> s tau_tilde)")
            if self.tau_tilde * scale > ANISOTROPY_INNER_MAX * h * h:
                raise UserInputError(
                    f"tau_tilde = {self.tau_tilde:.3g}{what} is {self.tau_tilde * scale / (h * h):.3g} h^2 (h = "
                    f"{h:.3g}), above {ANISOTROPY_INNER_MAX:g} h^2, where no step solves: scale gamma down or "
                    "lower tau_tilde")
        if self.tau_tilde * scale > TAU_TILDE_WARN_FACTOR * h * h:
            warnings.warn(StepSizeWarning(
                f"tau_tilde = {self.tau_tilde:.3g}{what} is {self.tau_tilde * scale / (h * h):.3g} h^2 (h = {h:.3g}, "
                f"the mean edge length): above about h^2 the step loses tangential convexity and the optimiser "
                f"clusters nodes (docs/theory/tau_tilde.md); use {'an effective ' if what else ''}tau_tilde <= h^2 "
                "and take large steps in tau instead"),
                stacklevel=3)
        low = TAU_TILDE_LOW_FACTOR * h * h * (1 - 1e-9)  # (h^2 / 1e4, one ulp below 1e-4 h^2, warned of itself)
        if self.tau_tilde * scale < low and self.main_solver(mesh.n_vertices) == "ipopt":
            warnings.warn(StepSizeWarning(
                f"tau_tilde = {self.tau_tilde:.3g}{what} is {self.tau_tilde * scale / (h * h):.3g} h^2 (h = {h:.3g}, "
                f"the mean edge length): below about {TAU_TILDE_LOW_FACTOR:g} h^2 IPOPT's steps fail "
                "(docs/theory/tau_tilde.md); use tau_tilde near h^2/100, or solver=newton-krylov, whose stopping "
                "test is relative"), stacklevel=3)
        self._min_tau = 1e-2 * h**4 if s.min_tau is None else s.min_tau
        self.relax_max_tau = 100 * self.tau if s.relax_max_tau is None else s.relax_max_tau
        if self.relax_max_tau < self.tau:
            raise UserInputError(f"relax_max_tau must be a number >= tau = {self.tau:g}, got {s.relax_max_tau!r}")

    @property
    def min_tau(self) -> float:
        """The step-size floor: ``min_tau`` when given, else 0.01 h^4, where h (the mean edge of the mesh the flow
        started on) is divided by :data:`REFINE_FACTOR` for each refinement (``refine_dihedral``): the edge of its
        finest part (as a refinement divides tau_tilde, ~ h^2, by REFINE_FACTOR^2). Measured: trimesh's box subdivided 3
        times (386 v) with V and A fixed, refined at steps 1 and 9 (386 -> 646 -> 681 v) near the corners that the flow
        sharpens into cones: its step problem after the second refinement is convex only below tau_c = 1.42e-6 (2.29e-5
        / 16.1) where the floor of the initial h was 4.1e-6, and the run failed at step 10; with the floor of the finest
        part (2.6e-7) it goes on (docs/guide/terms.md)."""
        if self.settings.min_tau is not None:
            return self._min_tau
        return self._min_tau / REFINE_FACTOR ** (4 * self._refinements)

    def _new_state(self) -> bool:
        """Whether the next step starts on a new discretisation: the first step, or the first after a refinement
        (``convex_start`` looks at its convexity limit)."""
        return self.k == 0 or self._refined_at == self.k

    def _state_name(self) -> str:
        """The state of :meth:`_new_state` in messages."""
        return "the initial state" if self.k == 0 else f"the state refined at step {self.k}"

    def _convex_start(self, tau: float, failed: int) -> float | None:
        """``convex_start``: the next step size of the first step (or of the first after a refinement,
        :meth:`_new_state`) below the step problem's convexity limit tau_c at X^k
        (:func:`~willmore_nlp.solvers.reduced.convexity_limit`), with adaptive or relax steps, after ``failed`` failed
        attempts: when a first look (:data:`~willmore_nlp.solvers.reduced.CONVEXITY_FIRST_RESTARTS`) finds tau_c <
        tau / :data:`CONVEX_FAR`, before the first attempt (``failed`` 0: newton-krylov's) or after it (1: other
        solvers'); after the first two attempts (2: at tau and tau / 2) when tau_c < tau / :data:`CONVEX_JUMP` (the
        restarts then :data:`~willmore_nlp.solvers.reduced.CONVEXITY_RESTARTS` unless the first look converged;
        already after the first attempt when a look before it did not converge). The step size is the largest tau /
        2^j not above tau_c / 2, or not above tau_c when that one is below the floor ``min_tau``. None: the first
        attempt at tau, or halve tau as usual."""
        from willmore_nlp.solvers.reduced import CONVEXITY_FIRST_RESTARTS, CONVEXITY_RESTARTS

        s = self.settings
        if not (s.convex_start and (s.adaptive or s.relax)):
            return None
        # the full look after two failures, and already after one when a first look before it found nothing (a
        # 28,212-vertex dumbbell: the first look's two cycles did not converge, the full one found tau / 1.65e5 in
        # 10 s, and the attempt at tau / 2 in between cost 200 s)
        looked = self._tau_c is not None and self._tau_c[2] == self.k and np.isnan(self._tau_c[0])
        tau_c = self._look_tau_c(tau, CONVEXITY_FIRST_RESTARTS if failed == 0 or (failed == 1 and not looked)
                                 else CONVEXITY_RESTARTS)
        if not tau_c < tau / (CONVEX_FAR if failed <= 1 else CONVEX_JUMP):  # (nan: not found)
            return None
        floor = min(self.min_tau, self.tau)
        for limit in (tau_c / 2, tau_c):
            j = int(np.ceil(np.log2(tau / limit)))
            if tau / 2**j >= floor:
                warnings.warn(f"step {self.k + 1}: the step problem is convex at {self._state_name()} only below "
                              f"tau = {tau_c:.3g} = tau / {tau / tau_c:.3g}; the {'next' if failed else 'first'} "
                              f"attempt is at tau / 2^{j} = {tau / 2**j:.3g} (convex_start=false "
                              f"{'halves instead' if failed else 'starts at tau'})", stacklevel=4)
                return tau / 2**j
        if failed == 2:  # (once: after the second failure)
            last = tau / 2**s.max_retries
            warnings.warn(f"step {self.k + 1}: the step problem is convex at {self._state_name()} only below tau = "
                          f"{tau_c:.3g} = tau / {tau / tau_c:.3g}, and the step sizes tau / 2^j below it are under the "
                          f"step-size floor min_tau = {floor:.3g}: the attempts go on halving to tau / "
                          f"2^{s.max_retries} = {last:.3g} (max_retries), {last / tau_c:.3g} times tau_c, where they "
                          f"may all fail (--set min_tau={tau_c / 4:.2g} lets the next one start below tau_c)",
                          stacklevel=4)
        return None

    def _look_tau_c(self, tau: float, restarts: int, dense: bool = False) -> float:
        """The step problem's convexity limit tau_c at X^k (:func:`~willmore_nlp.solvers.reduced.convexity_limit`
        with ``restarts`` and ``dense``; nan: not found), looked for once per number of restarts and state (a
        fallback solver's failures jump to the same step sizes)."""
        from willmore_nlp.solvers.reduced import ReducedSolver, convexity_limit

        fresh = self._tau_c is None or self._tau_c[2] != self.k  # (no look at this state yet)
        if fresh or (np.isnan(self._tau_c[0]) and self._tau_c[1] < restarts):
            z0 = self.problem.pack_z(self.X, self.Y)
            solver = self.solver if isinstance(self.solver, ReducedSolver) else None  # (newton-krylov: its factors)
            try:
                tau_c = convexity_limit(self.evaluator, z0, self.params(self.X, tau), restarts, solver, dense=dense)
            except np.linalg.LinAlgError:  # J_Y not positive definite at X^k (an anisotropy of a huge scale,
                # gamma2:1e20, exited 70 with this traceback: a new user's check): no look; the attempts say why
                tau_c = float("nan")
            self._tau_c = tau_c, restarts, self.k
        return self._tau_c[0]

    def _fixed_step_hint(self, tried: float, rejected: list[str]) -> str:
        """What a failed step of a flow with fixed steps (neither ``adaptive`` nor ``relax``, which take
        ``convex_start``) adds to its error when its solvers did not converge at any step size tried (``tried``: the
        smallest) and the step problem is convex at X^k only below a smaller tau_c (exact up to
        :data:`~willmore_nlp.solvers.reduced.CONVEXITY_DENSE_MAX` unknowns: ``convexity_limit``'s dense eigenproblem;
        above, its Lanczos estimate, never below the true tau_c). Measured (2026-12-02): the torus problem at tau = 5.9
        with tangential_weight = 1 failed at tau to tau / 16 (IPOPT, 100-200 iterations each); tau_c = tau / 421 (the
        Lanczos look said tau / 152); with adaptive = true its first step is taken at tau / 2^9 and the steps grow."""
        from willmore_nlp.solvers.reduced import CONVEXITY_RESTARTS, convexity_dense

        s = self.settings
        if s.adaptive or s.relax or self.problem.nh or not any(SOLVER_REASON in r for r in rejected):
            return ""
        # (convex_start never looks in a flow with fixed steps: a value cached at this state is this dense look's)
        tau_c = self._look_tau_c(tried, CONVEXITY_RESTARTS, dense=True)
        if not tau_c < tried:  # (nan: not found)
            return ""
        exact = convexity_dense(self.problem, dense=True)
        return (f"; the step problem is convex at this state only below tau = {tau_c:.3g} = tau / "
                f"{self.tau / tau_c:.3g}{'' if exact else ' or less (an estimate from above)'}: give tau = "
                f"{tau_c / 2:.2g} (tau_c / 2) or less, or adaptive = true (its first step starts below tau_c, "
                "convex_start, and the steps grow)")

    def _convex_far(self, tau: float) -> float | None:
        """tau_c when the first look of :meth:`_convex_start` found tau_c < tau / :data:`CONVEX_FAR` (a step
        problem that no attempt near tau solves with newton-krylov), else None. When the step sizes below tau_c are
        under the floor ``min_tau`` too, newton-krylov's first-step attempts are left to the ``fallback_solver`` (a
        noisy icosphere of 2,279 v, tau / tau_c = 2.8e5, tau_c under the floor: nine failed attempts of
        newton-krylov, then IPOPT's step at tau, 83 s; docs/guide/performance.md)."""
        return self._tau_c[0] if self._tau_c is not None and self._tau_c[2] == self.k and \
            self._tau_c[0] < tau / CONVEX_FAR else None

    def _relax_value(self, X: np.ndarray, Y: np.ndarray) -> float:
        """The energy relax=true watches at the state (X, Y): the Willmore energy, the anisotropic one (a
        scale-invariant anisotropic flow), or the scheme's energy where the flow decreases W + lam A, a Helfrich
        energy or an energy with outer constraints."""
        if self._relax_column == "energy":
            return self.discrete_energy(X, Y)
        if self._relax_column == "willmore_gamma":
            return anisotropic_willmore_energy(self.mesh.with_vertices(X), self.setup.anisotropy, self.energy_nodes)
        return geometry.willmore_energy(self.mesh.with_vertices(X), self.energy_nodes)

    def _watched(self, result: StepResult) -> float:
        """The energy relax=true watches (:meth:`_relax_value`) of an accepted state's result."""
        return {"energy": result.energy, "willmore_gamma": result.willmore_gamma}.get(self._relax_column,
                                                                                     result.willmore)

    def relax_message(self) -> str:
        """Why relax=true ended ("" while it has not)."""
        if not self.relaxed:
            return ""
        what = {"energy": "the scheme's energy (with lam, c0, a term that is not Moebius invariant, or an anisotropy "
                          "and outer constraints)",
                "willmore_gamma": "the anisotropic Willmore energy"}.get(self._relax_column, "the Willmore energy")
        if self.relax_reason == "small":
            why = (f"relaxed: step {self.k} ended {RELAX_WINDOW} steps that changed {what} by less than relax_tol = "
                   f"{self.settings.relax_tol:g} per nominal step")
        else:
            why = (f"relaxed: step {self.k} ended {RELAX_WINDOW} steps over which {what} rose with no edge flip (the "
                   "scheme's drift at rest)")
        why += self._above_origin()
        lowest, left = self.last_stability, f" ({self._kicks} saddle(s) left on the way)" if self._kicks else ""
        if not np.isfinite(lowest):  # (not tested: relax_check off, a curve, a surface above the size limit, or the
            # iterative eigensolver failed)
            if self.untested:
                return why + f"; not tested for a saddle: {self.untested}"
            big = self.settings.relax_check and self.mesh.d == 2 and self.mesh.m == 3 and not self._spectrum_fits()
            return why + (f"; not tested for a saddle: {self.mesh.n_vertices} vertices, above STABILITY_MAX_VERTICES = "
                          f"{STABILITY_MAX_VERTICES}" if big else "")
        if lowest >= -SADDLE_TOL and not np.isfinite(self.last_gap):
            return why + (f"; flat on normal motions: lowest eigenvalue {lowest:.3g} (not below -SADDLE_TOL, and its "
                          f"quadratic model has no minimum){left}")
        if _off_rest(lowest, self.last_gap):
            return why + (f"; not at rest on normal motions: lowest eigenvalue {lowest:.3g}, the energy "
                          f"{self.last_gap:.2g} of itself above its quadratic model's minimum there (above "
                          f"POLISH_MAX_GAP = {POLISH_MAX_GAP:g}: not polished; gone on past {self._go_ons} such ends "
                          f"already, MAX_GO_ON){left}")
        if lowest >= -SADDLE_TOL and self.last_gap > self.settings.relax_tol:  # (a new user's v = 0.6 prolate vesicle
            # was called "a minimum" 1.8e-3 of its energy above it; relax_tol = 1e-7 went on to 1.2e-9)
            return why + (f"; near a minimum on normal motions: lowest eigenvalue {lowest:.3g}, the energy "
                          f"{self.last_gap:.2g} of itself above its quadratic model's minimum there, more than "
                          f"relax_tol = {self.settings.relax_tol:g} (the polish left it there; a smaller relax_tol "
                          f"goes on){left}")
        if lowest >= -SADDLE_TOL:
            return why + (f"; a minimum on normal motions: lowest eigenvalue {lowest:.3g}, the energy "
                          f"{self.last_gap:.2g} of itself above its quadratic model's minimum there{left}")
        return why + (f"; a saddle: lowest eigenvalue on normal motions {lowest:.3g}, "
                      + (f"left {MAX_SADDLE_KICKS} times already (MAX_SADDLE_KICKS)" if self._kicks >= MAX_SADDLE_KICKS
                         else "no move along its mode lowered the energy"))

    def _above_origin(self) -> str:
        """relax_message's note on a relaxation that ended above the watched energy it began with ("" otherwise):
        the mesh control's actions between the steps can raise it (each mesh discretises the surface anew: a trimesh
        uv sphere flowed as given, W 24.9273 -> 24.9642, its remeshing +0.126, its steps -0.089)."""
        end, start = self._relax_value(self.X, self.Y), self._relax_origin
        if not end > start:
            return ""
        name = {"energy": "the scheme's energy", "willmore_gamma": "w_gamma"}.get(self._relax_column, "W")
        head = f"; {name} ended above its start, {start:.6g} -> {end:.6g} ({100 * (end / start - 1):+.2g} %)"
        control = self._control_change
        if not np.isfinite(control):
            return head
        return head + (f": the mesh control's actions after the steps changed it by {control:+.4g} in all (each mesh "
                       f"discretises the surface anew), the steps and moves at rest by {end - start - control:+.4g}")

    def _relax_start(self, willmore: float) -> None:
        """Start the relax window at a state of energy ``willmore`` (:meth:`_relax_value`), with no step-size
        back-off."""
        self._relax_window: list[tuple[float, bool, float]] = [(willmore, False, 0.0)]
        self._backoff, self._hold, self._last_tau = 1, 0, 0.0
        self._relax_origin, self._control_change = willmore, 0.0  # (relax_message: where the watched energy began,
        # and what the mesh control's actions after the steps changed it by since)

    def _control_share(self, row: dict[str, Any]) -> float:
        """What the mesh control's action after a step changed the watched energy by (:meth:`_relax_value`): the
        state after it (before a move at rest, ``relax_check``) against the stepped state, read off the step's
        :meth:`StepResult.row` or its history.csv row; 0 when the mesh control did not act, nan when the row does not
        tell (the anisotropic energy has no before value)."""
        if not row.get("remesh_action"):
            return 0.0
        column = self._relax_column
        if column == "willmore_gamma":
            return float("nan")
        before = "willmore_before_remesh" if column == "willmore_energy" else "energy_before_remesh"
        moved = "willmore_before_move" if column == "willmore_energy" else "energy_before_move"
        after = row.get(moved) if row.get(moved) not in (None, "") else row[column]
        return float(after) - float(row.get(before) or "nan")

    def _cut_by_t_end(self, tau: float, nominal: float, fresh: bool) -> bool:
        """Whether a first try ``tau`` of adaptive or relax steps is shorter than the step-size control's (from the
        ``nominal`` tau), i.e. cut to land on ``run``'s t_end; never for the first step of a new state (``fresh``),
        whose first try may be ``convex_start``'s. The same test replays a run's history (:meth:`restart`)."""
        s = self.settings
        if fresh or not (s.adaptive or s.relax):
            return False
        if s.relax:
            wish = min(self.relax_max_tau, nominal if np.isinf(self._tau_adapt) else self._tau_adapt)
        else:
            wish = min(nominal, self._tau_adapt)
        return tau < wish

    def _grow_tau(self, tau: float, attempt: int) -> None:
        """Set the step size the next step starts from (``adaptive`` and ``relax``), after a step accepted at tau.

        A step accepted at its first attempt doubles tau, one accepted after retries keeps it, and the control
        backs off after a step with retries: it holds tau for 2, 4, 8, ... first-attempt steps (doubling the
        hold at each such step, a failed doubling or a retry at the held tau; back to none when a doubled step
        succeeds), so a flow whose steps cannot reach twice their size does not waste every other attempt on it
        (not doubling it after retries at the held tau was slower: docs/guide/runs.md).
        """
        if attempt:
            cap = self.settings.adaptive_max_wait
            self._backoff = 2 * self._backoff if not cap else min(2 * self._backoff, cap)
            self._hold = self._backoff
        elif tau > self._last_tau:  # a grown step succeeded
            self._backoff, self._hold = 1, 0
        else:
            self._hold = max(0, self._hold - 1)
        self._tau_adapt = tau if attempt or self._hold else 2 * tau
        self._last_tau = tau

    def _rest_tau_tilde(self, retries: int, tau: float, w: float, area: float, drift: bool) -> bool:
        """Count the accepted state (Willmore energy ``w``, area ``area``; ``drift``: its step's motion was the
        drift, ``DRIFT_SHARE``) toward rest and halve tau_tilde (``rest_tau_tilde``) after ``RELAX_WINDOW``
        consecutive steps at rest; True when it halved.

        A step is at rest when it was taken at its first attempt with tau >= the nominal tau and either its
        motion was the drift or the Willmore energy (scale invariant) of the accepted, repaired state differs
        from the previous one by less than ``rest_tol`` relative per unit of the surface's own time scale L^4
        (L^2 = area / 4 pi), i.e. by less than ``rest_tol tau / L^4`` in the step (per step alone, a torus
        flowing slowly at tau = 1e-3 counted as at rest). At rest the scheme still moves a closed surface: its
        O(tau_tilde) drift shrinks it (a sphere: dR/dt = -16 tau_tilde / R^5, a collapse at t = R^6 / (96
        tau_tilde)), which the smaller tau_tilde slows down by the same factor (and ``rest_dilation`` undoes).
        The energy test alone missed the drift of a coarse sphere (a refined trimesh cylinder, R = 0.77, h^2/100,
        tau = h: the drift's own distortion of the mesh changed W by 5e-5 per step, above ``rest_tol``, for 24
        steps while the volume fell to 42 %). Y[X] is solved again for the new tau_tilde.
        """
        L4 = geometry.length_scale(area, 2, True) ** 4
        still = (retries == 0 and tau >= self.tau
                 and (drift or abs(w - self._rest_w) <= self.settings.rest_tol * tau / L4 * abs(w)))
        self._rest_w = w
        self._rest_steps = self._rest_steps + 1 if still else 0
        floor = self.settings.rest_tau_tilde * self.tau_tilde_initial
        if self._rest_steps < RELAX_WINDOW or self.tau_tilde <= floor:
            return False
        self.tau_tilde = max(floor, self.tau_tilde / 2)
        self.Y = self._solve_y(self.X, tau)
        self.lam_g = None
        self._rest_steps = 0
        return True

    def _relax_test(self, willmore: float, tau: float, action: str, newton: bool = False) -> bool:
        """Record an accepted state in the relax window and say whether the relaxation has ended.

        A state counts unless its step was followed by smoothing, remeshing or a move off a saddle (``action``; the
        light repair follows every step and counts); such a state restarts the window from itself (and a move off a
        saddle is counted, ``relax_check``). The relaxation ends when over the window the Willmore energy changed by
        less than ``relax_tol`` relative per nominal step (a step of tau_i < tau counts as tau_i / tau steps: a flow
        held at small steps by retries still ends; a Newton step on normal motions, ``newton``, as one step whatever
        the step size its time steps were held at: counted as tau_i / tau, a new user's cylinder with V and A fixed
        crawled 100 Newton steps at tau / 256 toward a saddle that the test found at step 141 and failed at step 161;
        counted as one step, its relaxation ended at step 77 in 18 s, on a saddle that it had left MAX_SADDLE_KICKS
        times, w = 1.404 8 pi, where time steps throughout end at step 248 in 110 s, w = 1.322 8 pi), or rose with no
        Delaunay flip in the window (the scheme's own drift at rest; a flip alone moves the energy by ~1e-3 on 642
        vertices; not after a move off a saddle, from which the energy may rise first).
        """
        parts = set(action.split("+"))
        entry = (willmore, "flips" in parts, 1.0 if newton else min(1.0, tau / self.tau))
        self._kicks += "saddle" in parts
        ok = not ({"smooth", "saddle"} | NEW_VERTICES) & parts
        w = self._relax_window = [*self._relax_window, entry][-RELAX_WINDOW - 1:] if ok else [entry]
        if len(w) <= RELAX_WINDOW:
            return False
        change = w[0][0] - w[-1][0]
        steps = sum(s for _, _, s in w[1:])
        small = abs(change) <= steps * self.settings.relax_tol * abs(w[-1][0])
        rose = change < 0 and not any(f for _, f, _ in w[1:]) and not self._kicks  # (off a saddle it may rise first)
        self.relax_reason = "small" if small else "rose" if rose else ""
        return small or rose

    def restart(self, X: np.ndarray, Y: np.ndarray, t: float, k: int,
                lam_g: np.ndarray | None = None, last_tau: float | None = None, last_retries: int = 0,
                simplices: np.ndarray | None = None, free: np.ndarray | None = None,
                iterations: list[int] | None = None, history: list[dict[str, Any]] | None = None,
                tau_tilde: float | None = None, rest_steps: int = 0,
                warm: dict[str, Any] | None = None) -> None:
        """Continue from a saved state (X^k, Y[X^k], t, k), e.g. a run directory's checkpoint.

        With the ``Y``, multipliers ``lam_g`` and solver state ``warm`` that the flow held at that state (all
        are in every checkpoint), the following steps are bit-identical to those of a flow that was
        never interrupted.

        Parameters
        ----------
        X, Y : (N, m) positions and inner step of the state
        t : its time
        k : its step number
        lam_g : constraint multipliers of the step that produced it (warm starts), optional
        last_tau, last_retries : step size and retries of the step that produced it (adaptive
            step-size control continues from them; None when the state is the initial one)
        simplices : (K, 3) connectivity of the state when the mesh control changed it (the step
            NLP is rebuilt for it); None: the current connectivity
        free : (N,) bool free-vertex mask of a clamped problem on that connectivity
        iterations : solver iterations of the accepted steps up to this state (the iteration budget
            is a multiple of their median over the last ``BUDGET_WINDOW``), those of the main solver of each
            step (:meth:`budget_iterations` picks them from the history); None: an empty history
        history : rows (:meth:`StepResult.row`, e.g. read from history.csv) of the states up to this one, from
            the initial state on: the relax test continues from its window over them; None: from this state
        tau_tilde, rest_steps : the state's tau_tilde and count of steps at rest (``rest_tau_tilde``; columns of
            its row); None: the flow's tau_tilde is kept
        warm : :meth:`warm_state` at that state (what the step solver carried into the next solve); None or {}:
            a new solver
        """
        X = np.array(X, dtype=float)
        Y = np.array(Y, dtype=float)
        if simplices is not None and not np.array_equal(simplices, self.mesh.simplices):
            boundary = self.boundary
            if boundary is not None and not np.array_equal(free, boundary.free):
                from willmore_nlp.boundary import Boundary

                if free is None or boundary.conormal is not None or boundary.ring is not None:
                    raise ValueError("restart: a clamped problem on a new connectivity needs its free mask "
                                     "(and has no explicit co-normal or ring)")
                boundary = Boundary(np.asarray(free, bool), boundary.variant)
            self._build(Mesh(X, np.asarray(simplices), self.mesh.source), boundary)
        if X.shape != self.mesh.vertices.shape or Y.shape != X.shape:
            raise ValueError(f"restart: state has shape {X.shape}/{Y.shape}, the mesh has {self.X.shape}")
        if not (np.all(np.isfinite(X)) and np.all(np.isfinite(Y))):
            raise ValueError("restart: the state has non-finite values")
        self.X, self.Y, self.t, self.k = X, Y, float(t), int(k)
        self._X_prev = self.X
        self._paused = self._drifting = False  # (REST_SPEED: from the state's history row below)
        self._slide = 0.0
        self.lam_g = None if lam_g is None else np.array(lam_g, dtype=float)
        self._accepted_iterations = [int(n) for n in (iterations or [])][-BUDGET_WINDOW:]
        w0 = self._relax_value(X, Y)  # (W, the rest rule's, whenever that rule runs: it runs without relax)
        self._relax_start(w0)
        self._kicks, self._go_ons, self.last_stability, self.last_gap = 0, 0, float("nan"), float("nan")
        replayed = False  # the relax window and step-size back-off rebuilt up to this state from its history
        refines = [int(float(r["step"])) for r in history or []
                   if "refine" in str(r.get("remesh_action") or "").split("+") and int(float(r["step"])) <= self.k]
        self._refinements, self._refined_at, self._tau_c = len(refines), max(refines, default=-1), None
        column = self._relax_column
        for r in history or []:
            replayed = "willmore_energy" in r and int(float(r["step"])) == self.k
            if replayed:
                pause = float(r.get("mesh_pause") or 0)
                self._paused, self._drifting = pause == 1, pause == 2
                self._slide = float(r.get("mesh_slide") or 0)
            if "willmore_energy" not in r:  # a checkpoint without its history row: the window starts after it
                self._relax_window = []
            elif int(float(r["step"])) == 0:
                self._relax_start(float(r[column]))
            else:
                newton = r.get("solver") == NEWTON_SOLVER
                step, retries = int(float(r["step"])), int(float(r["retries"]))
                fresh = step == 1 or step - 1 in refines
                if not newton and (retries or not self._cut_by_t_end(float(r["tau"]), self.tau, fresh)):
                    self._grow_tau(float(r["tau"]), retries)
                ended = self._relax_test(float(r[column]), float(r["tau"]), str(r.get("remesh_action") or ""),
                                         newton)
                self._control_change += self._control_share(r)
                if r.get("stability") not in (None, "") and np.isfinite(float(r["stability"])):
                    self.last_stability, self.last_gap = float(r["stability"]), float(r.get("stability_gap", "nan"))
                    if ended and not float(r.get("relaxed") or 0):  # (the run went past this end: MAX_GO_ON)
                        self._go_on(self.last_stability, self.last_gap)
        if not replayed:
            self._tau_adapt = (float("inf") if last_tau is None
                               else float(last_tau) * (2.0 if int(last_retries) == 0 else 1.0))
        if tau_tilde is not None and np.isfinite(float(tau_tilde)):
            self.tau_tilde = float(tau_tilde)
        self._rest_steps = int(rest_steps)
        self._rest_w = w0
        if warm:
            name = str(warm["solver"])
            if name in self._step_solvers():
                if self.solver.name != name:
                    self._make_solver(name)
                self.solver.set_warm_state({k: v for k, v in warm.items() if k != "solver"})

    def warm_state(self) -> dict[str, Any]:
        """What the step solver carries into its next solve (newton-krylov: where its preconditioner was built,
        :meth:`~willmore_nlp.solvers.newton_krylov.NewtonKrylovSolver.warm_state`) with the solver's name, for a
        checkpoint (:meth:`restart`); {} when it carries nothing beyond ``lam_g``."""
        state = self.solver.warm_state() if hasattr(self.solver, "warm_state") else {}
        return {"solver": self.solver.name, **state} if state else {}

    def run(
        self,
        t_end: float | None = None,
        steps: int | None = None,
        callback: Callable[[StepResult], None] | None = None,
    ) -> list[StepResult]:
        """Step until the time ``t_end`` (absolute; the last step is shortened to hit it) or for ``steps`` more steps
        (counted from the current state: a flow at step 3 ends at step 6 after ``run(steps=3)``, where the command
        line's ``--steps`` is the run's total).

        With ``relax=True`` it stops earlier, after the step that ended the relaxation
        (:attr:`relaxed` is then True). ``callback`` is called with every accepted StepResult.
        Returns the accepted steps (a list, once the run ends); a step that fails raises :class:`FlowError` with
        the steps accepted before it in its ``results`` (the flow stays at the last of them).
        """
        if t_end is None and steps is None:
            raise UserInputError("run needs t_end or steps")
        if t_end is not None and not (is_number(t_end) and 0 <= t_end < math.inf):
            raise UserInputError(f"run: t_end must be a finite time >= 0, got {t_end!r}")
        if steps is not None and not (is_number(steps) and math.isfinite(steps) and float(steps).is_integer()
                                      and steps >= 0):
            raise UserInputError(f"run: steps must be an integer >= 0, got {steps!r}")
        out: list[StepResult] = []
        nominal = self.tau
        self._run_tau = nominal
        try:
            while True:
                if steps is not None and len(out) >= steps:
                    break
                if t_end is not None:
                    remaining = t_end - self.t
                    if remaining <= 1e-12 * max(1.0, abs(t_end)):
                        break
                    self.tau = min(nominal, remaining)
                    self._t_end = float(t_end)
                try:
                    r = self.step()
                except FlowError as exc:
                    exc.results = out
                    raise
                out.append(r)
                if callback is not None:
                    callback(r)
                if r.relaxed:
                    break
        finally:
            self.tau = nominal
            self._t_end = float("inf")
            self._run_tau = None
        return out
