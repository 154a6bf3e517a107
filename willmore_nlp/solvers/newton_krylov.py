"""``newton-krylov``: reduced-space Newton with preconditioned CG and sparse Cholesky factorisations.

The step NLP is solved, like the reduced solvers of :mod:`willmore_nlp.solvers.reduced`, as the
minimisation of W^(X) = W(X, Y[X]) over the free X; the adjoint gradient and the exact
second-order adjoint Hessian-vector products are the ones of that module (shared code). What
differs is the linear algebra and the globalisation:

* J_Y factorisation. Isotropic: J_Y = (M[X] + tt L[X]) (x) I_m in node-major order, so one N x N
  sparse Cholesky (:mod:`willmore_nlp.solvers.cholesky`) serves
  the m coordinates; Y[X] is one such solve. Anisotropic: J_Y is the Hessian of a strictly convex
  inner energy, factorised as a whole (also SPD) inside the damped inner Newton of
  :meth:`StepEvaluator.solve_y`.
* Newton step. The reduced Newton system (Hess W^ + delta D) d = -grad W^ is solved by conjugate
  gradients to the relative residual eta = min(cg_forcing, sqrt(|grad|/|grad_0|)) (0.5 instead of
  cg_forcing for a shifted system, a safeguard only; the step expected to be the last one to
  0.1 gtol / |grad|, so that the result is accurate to the tolerance and not just below it),
  preconditioned with the Gauss-Newton matrix

      B = D + 2 tau K^T Ml^-1 K,   K = (J_X + J_Y S) / tt,

  D the exact Hessian of the distance part of W (2 M[Xk] (x) I for the paper's scheme; with a
  tangential weight or control the corresponding quadratic form), Ml the lumped mass on the Y
  nodes and S the injection of the free X dofs into the Y dofs. B is the Gauss-Newton Hessian of
  W^ with J_Y^-T M J_Y^-1 replaced by Ml^-1. Its factorisation costs as much as some 50 (2,562
  vertices) to 60 (10,242) CG iterations, so it is kept (also for the next solve with the same tau)
  and rebuilt after ``cg_rebuild`` CG iterations with it, when X has moved more than
  ``precond_move`` h (h the mean edge length of Xk; ``precond_move_indefinite`` h once CG met negative
  curvature in the solve) since it was built, or when a CG solve with a B
  built at another point reaches ``cg_stale`` iterations (then CG restarts with the new B). (A rule
  on measured times would make the iterates depend on the machine's load.) A B carried into the next
  solve makes that step depend on more than the flow's state: :meth:`NewtonKrylovSolver.warm_state`
  gives B's build point to the run directory (``solver_state.npz``) and
  :meth:`NewtonKrylovSolver.set_warm_state` rebuilds the same B on resuming, so that a resumed run takes
  the same steps bit for bit (without it the steps of a flow near rest differed by 1e-9 after a resume;
  building B afresh in every solve instead took two factorisations of B per step where one did, steps
  2-5 of the 10,242-vertex benchmark sphere).
* Indefiniteness. When CG meets a direction of non-positive curvature the shift delta D is raised
  (delta = 1 first, then 10 delta) and CG restarts; the next Newton iteration starts from delta / 10
  (0 below 1e-3), so the final iterations are pure Newton. A shift above ``max_shift`` (1e3) ends the
  solve unconverged: the steps of the measured convergent solves needed at most 10, while the
  first step of the genus-2 surface at tau = h needed 1e4-1e6 and crawled through its 50 iterations
  (both solvers converge there only at tau <= h/512).
* First step of an indefinite solve. When CG meets negative curvature in the first Newton system of a
  solve (a first step from an initial mesh: the reduced Hessian at X^0 is indefinite with the adjoint
  multiplier), that system is solved accurately (CG to ``first_cg_tol``) with the shift ``first_shift`` D
  (300; 1000 above 10,242 free vertices: ``FIRST_SHIFT_LARGE``; x10 while CG still meets negative curvature) and the
  solve continues by the full-space (SQP)
  iteration: Newton on the KKT system of min W s.t. g = 0, each system reduced as above with
  dz_p = [0; -J_Y^-1 g], (Z^T H Z + delta D) dx = -Z^T (grad W + H dz_p), dy = -J_Y^-1 (g + J_X dx), the
  Hessian H with the multiplier of the previous KKT step lam+ = -J_Y^-T (f_Y + (H dz)_Y) instead of the
  adjoint multiplier of the current X, backtracking on the augmented Lagrangian W + lam . g + rho/2 |g|^2
  (Armijo along (dz, lam+ - lam), rho raised where the slope needs it; a second-order correction Y = Y[X]
  of a rejected full step, a step cap of ``step_cap`` h) and the reduced gradient at Y = Y[X] as the final
  test. When a later system meets negative curvature again, the multiplier did not help: right after the first
  full-space step the reduced iteration restarts from X^0 with the preconditioner's state of the start (its path
  as without the attempt, the attempt's iterations later; flattened caps, where going on from the full-space
  iterate took 22 Newton iterations instead of 15); after ``HANDBACK_AFTER`` or more full-space steps it goes on
  from the current iterate with Y = Y[X] (the 40,962-vertex sphere, whose fourth system meets it: 22 Newton
  iterations with the restart). The first step's
  multiplier makes H positive definite on the constraint's tangent space where the adjoint one is not
  (tested densely): step 1 of the benchmark spheres took 7 / 6 / 7 Newton iterations at 642 / 2,562 /
  10,242 vertices instead of 8 / 11 / 13 (IPOPT 6 / 6 / 5). A first system without negative curvature
  (a flow's later steps) is the reduced iteration's, unchanged.
* The guarded pass (``guarded``). On noisy inputs the step problem itself is far from convex at X^0 (its reduced
  Hessian D + tau R is positive definite only below tau = h/1,291 on a noisy 640-vertex torus and h/38,606 on a
  trimesh cone, with local negative modes), and descent on W^ with Y = Y[X] crushes a triangle where IPOPT's
  infeasible iterates go round to a healthy solution 0.7-2.9 h away. A solve that met negative curvature and ended
  "too indefinite", with a failed line search or with the preconditioner's factorisation failed at an iterate (its
  triangles crushed; without outer constraints: the full-space iteration's domain) is therefore solved once more from
  X^k, in the full-space iteration from its first step on, also where the first Newton system is positive definite (a
  clean trimesh torus 128 x 64 at h/2 meets negative curvature only later: its guarded pass had then replayed the
  reduced iteration with the larger shifts, crawling through 50 iterations in 75 s to a failure, where the full-space
  one converges in 24 at 0.3 h per step, 17 s for the attempt), staying there (no hand-back, no restart; shifts up to
  ``GUARD_SHIFT``), with trial points that flip a triangle or put an angle below ``GUARD_ANGLE`` times the smallest
  angle of X^k halved in the merit search, full-space steps of at most ``GUARD_STEP`` h and shifted systems after the
  first cut at ``GUARD_CG`` CG iterations (the truncated direction taken when it descends); its iterations are bounded
  by ``max_iter`` alone, not by the flow's first-step budget, and it ends as failed once the guard has refused
  ``GUARD_REFUSALS`` trial points (converged passes needed 0-4, failed ones ran to 366-477). Measured (first steps,
  direct solves): it finds IPOPT's solutions (the same smallest angle and largest move) on a noisy torus at h/32 (the
  first pass: h/64), on a subdivided cylinder at h/8 (h/64) and on the cone at h/8 (the first pass fails at every
  tau), each solve in 1-5 s; failing, it fails in 1-6 s at these sizes (600-800 vertices); a noisy 10,192-vertex
  torus's first step at h/32 in 192 s where IPOPT took 939 s (docs/guide/performance.md). A nonlinear (anisotropic)
  inner equation runs it too, while its first pass stays in the reduced iteration (a full-space first pass there
  converged no further on the gamma1 ellipsoid below and needed the guarded pass at tau = 0.00625 where the reduced
  one converges): the 642-vertex ellipsoid 1:1:1.4 with gamma1 and tau_tilde = h^2/100 (a new user's check) had failed
  at tau = 0.05 (the reduced iteration crushed a triangle, area 0.31 -> 0.0036 h^2, its Y triangle to 1.7e-11 h^2, and
  B = D + GN, eigenvalues up to 6e22 against D's 0.011, failed its Cholesky factorisation) and at 0.0125 ("too
  indefinite"), where IPOPT took 0.05; the guarded pass takes both, to IPOPT's X within 4.4e-10 h. Smooth inputs never
  reach it (the first pass converges): their steps are unchanged bit for bit. The flow allows it per attempt
  (``guard_allowed``): not for an attempt above the last accepted step size (an adaptive doubling), which is retried
  at that size instead.
* Globalisation (reduced iteration). Backtracking (halving) line search with the Armijo condition on W^. A step whose
  predicted decrease is below the rounding level of W^ (100 eps |W^|) is accepted when it reduces
  |grad W^|_inf instead, whatever W^ does there (the last, quadratically convergent iterations:
  at 40,962 vertices the evaluation noise of W^ exceeded 100 eps |W^| and full Newton steps were
  rejected on it); only there can W^ rise, by what the predicted decrease says is noise.

* Outer constraints (volume, area; :mod:`willmore_nlp.solvers.reduced`). Every iterate is feasible
  (restored after each trial step); CG runs in the null space of the reduced constraint Jacobian C,
  the preconditioner projected in its own inner product, s = B^-1 r - B^-1 C^T (C B^-1 C^T)^-1 C B^-1 r,
  on the Hessian of the reduced Lagrangian W^ + mu . h^, and stops on the projected residual
  sqrt(r . s); grad W^ below is then the projected gradient. Without outer constraints nothing changes.

Stopping test: |grad W^|_inf <= tol * max(|grad W(z0)|_inf, tiny), i.e. relative to the size of the
step problem's own objective gradient at the start (the Willmore part 2 tau/tt^2 M (Y - X) does not
vanish when the flow is at rest), the reduced counterpart of IPOPT's dual infeasibility; the
primal infeasibility is zero to the inner solve's accuracy at every iterate.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp

from willmore_nlp import geometry
from willmore_nlp.mesh.topology import edge_lengths, unique_edges
from willmore_nlp.mesh.validate import face_normals
from willmore_nlp.model.evaluator import StepEvaluator
from willmore_nlp.settings import BOOL, integer, one_of, option, real
from willmore_nlp.solvers.base import SolveResult, register_solver
from willmore_nlp.solvers.cholesky import (
    BACKENDS,
    BLAS,
    FullFactor,
    KronFactor,
    SymmetricFactor,
    other_blas_one_thread,
)
from willmore_nlp.solvers.ipopt import SolveMonitor
from willmore_nlp.solvers.reduced import ReducedSettings, ReducedSolver, _Point

REST_MOTION = 1e-6
"""The stopping test's scale is at least the distance term's gradient for a motion of this many mean edges h (its
tolerance then asks for the step's X to about tol x 1e-6 h): a step whose start has a gradient of 0 (a flow at exact
rest) is solved where it starts."""

HANDBACK_AFTER = 2
"""Full-space steps after which negative curvature hands the solve to the reduced iteration at the current iterate
(fewer: it restarts from X^0; module docstring)."""

GUARD_ANGLE = 0.25
"""Guarded pass (module docstring): a full-space trial X with a flipped triangle or an angle below this fraction of the
smallest angle of X^k is shortened (0.5 refused the solutions IPOPT finds on a noisy torus, 9.07 of 21.4 deg)."""

GUARD_STEP = 0.3
"""Guarded pass: largest full-space step in X, in mean edges h of X^k (1 h: the cone and the cylinder failed at large
tau)."""

GUARD_CG = 50
"""Guarded pass: CG iterations of a shifted full-space system after the first; the truncated direction is taken when it
is a descent direction."""

GUARD_SHIFT = 1e7
"""Guarded pass: the largest shift (in units of D) instead of ``max_shift``."""

GUARD_REFUSALS = 40
"""Guarded pass: trial points the mesh guard may refuse in all before the pass ends as failed. Measured (first steps
of the cone, the cylinder, the noisy torus and capsule of docs/guide/performance.md, tau = h ... h/32): every
converged pass had 0-4 refusals, every failed one 366-477 (15,190-vertex capsule: 377 in 83 s), spent over 20-42
iterations of steps the guard kept shortening. In a long genus-2 flow (2026-11-29, 1,818 v, steps 301-350 of the
local-refinement run of docs/guide/mesh_quality.md) no accepted step needed a guarded pass, and its 12 failed attempts
(at twice the step; most ended here) took 411 Newton iterations with 40, 377 with 10 (the same steps bit for bit): the
refusals come at the end of a failing pass, so a lower limit saves little (8 %; 16 % on a capsule's first step)."""


FIRST_SHIFT = 300.0
"""The first shift (``first_shift`` unset) of solves with up to :data:`FIRST_SHIFT_VERTICES` free vertices (step 1 of
the benchmark spheres, Newton iterations at 642 / 2,562 / 10,242 vertices: 30: 7 / 10 / -, 100: 6 / 6 / 11, 300:
7 / 6 / 7, 1000: 8 / 7 / 9; a remeshed ellipsoid 1:1:1.3 of 4,598 vertices: 11 at 300, 14 at 1000)."""

FIRST_SHIFT_LARGE = 1000.0
"""The first shift (``first_shift`` unset) above :data:`FIRST_SHIFT_VERTICES` free vertices. Measured (step 1, Newton
iterations, one BLAS thread; docs/guide/performance.md): the 40,962-vertex benchmark sphere 13 at 300, 12 at 500, 10 at
1000 (81.5 s and 52.4 s, run one after the other); a remeshed ellipsoid 1:1:1.3 of 19,476 vertices 34 at 300 (69 s),
34 at 524 (78 s), 17 at 1000 (64 s).
A power law through 300 at 10,242 and 1000 at 40,962 vertices (N^0.87: 524 there) was no better than 300 at 19,476.
Against: trimesh's capsule repaired to 11,977 vertices, whose first step was taken at tau/4 in 201 s (at tau/2 in 189 s
with 300)."""

FIRST_SHIFT_VERTICES = 10_242
"""Free vertices up to which the first shift is :data:`FIRST_SHIFT`, above which :data:`FIRST_SHIFT_LARGE` (the
10,242-vertex benchmark sphere: 7 Newton iterations at 300, 9 at 1000; a remeshed ellipsoid of 9,376: 15 and 10, the
crossover)."""


@dataclass(frozen=True)
class NewtonKrylovSettings(ReducedSettings):
    """Options of ``newton-krylov`` (tolerance: see the module docstring).

    Attributes
    ----------
    tol : float
        Relative tolerance on the reduced gradient.
    max_iter : int
        Newton iterations.
    armijo : float
        Sufficient-decrease constant of the line search.
    cholesky : str
        Sparse Cholesky backend: "auto", "cholmod" or "scipy" (:mod:`willmore_nlp.solvers.cholesky`).
    cg_max_iter : int
        CG iterations per Newton system.
    precond_move : float
        Rebuild the preconditioner B when X moved more than this times the mean edge length h, in a solve
        whose CG has met no negative curvature. Measured (benchmark spheres at tau = 0.2 h, ellipsoids at
        tau = h, steps after the first): the first Newton step of a time step moves X by 0.16-0.42 h; a B built
        before it still serves that step's loose CG solve and then fails the next, tighter one after
        ``cg_stale`` wasted iterations. 0.1 rebuilds once per step at the second Newton system instead
        (the same builds, 15-25 CG iterations per step instead of 45-59, 28 % less time per step at 10,242
        vertices); a flow whose steps move less (at rest) keeps B across steps.
    precond_move_indefinite : float
        The same threshold once CG has met negative curvature in the solve (shifted Newton systems, the
        full-space iteration of a first step): 0.5. The shifted path is sensitive to the preconditioner (it
        decides where CG detects negative curvature): with 0.1 there the first step of the 2,562-vertex
        ellipsoid 1:1:2 at tau = h failed three times ("too indefinite") where 0.5 converges in 49 iterations.
    cg_rebuild : int
        Rebuild B after this many CG iterations with it.
    cg_stale : int
        A CG solve with a B built at another point that reaches this many iterations is restarted with B
        rebuilt at the current point.
    cg_forcing : float
        Largest CG forcing term (relative residual of a Newton system).
    max_shift : float
        The solve stops (not converged) when the shift of a Newton system would exceed ``max_shift`` D: the
        step problem is then far from convex at X^k (a tau too large for the shape), and the flow retries
        with tau/2 at once instead of after ``max_iter`` damped iterations.
    first_shift : float or None
        Shift (in units of D) of the first Newton system of a solve when CG meets negative curvature in it
        unshifted; that system is then solved to ``first_cg_tol`` and the solve continues by the full-space
        (SQP) iteration with its multiplier (module docstring). Measured on the benchmark spheres (step 1,
        Newton iterations at 642 / 2,562 / 10,242 vertices): 30: 7 / 10 / -, 100: 6 / 6 / 11, 300: 7 / 6 / 7,
        1000: 8 / 7 / 9. Unset (default): 300 up to 10,242 free vertices, 1000 above (:data:`FIRST_SHIFT`,
        :data:`FIRST_SHIFT_LARGE`, :data:`FIRST_SHIFT_VERTICES`).
    first_cg_tol : float
        CG relative residual of that shifted first system.
    step_cap : float
        Largest step in X of the full-space iteration, in units of the mean edge length h of X^k (a longer
        Newton step is scaled down to it before the line search).
    guarded : bool
        A solve that met negative curvature and ended "too indefinite" or with a failed line search is solved
        again from X^k by the guarded pass (module docstring); false: it fails at once (the flow retries).
    """

    solver = "newton-krylov"
    tol: float = option(1e-9, real(0, lo_open=True))
    max_iter: int = option(50, integer(1))
    cholesky: str = option("auto", one_of(*BACKENDS))
    cg_max_iter: int = option(300, integer(1))
    precond_move: float = option(0.1, real(0, lo_open=True))
    precond_move_indefinite: float = option(0.5, real(0, lo_open=True))
    cg_rebuild: int = option(60, integer(1))
    cg_stale: int = option(25, integer(1))
    cg_forcing: float = option(0.1, real(0, 1, lo_open=True))
    max_shift: float = option(1e3, real(0, lo_open=True))
    first_shift: float | None = option(None, real(0, lo_open=True, unset="300; 1000 above 10,242 free vertices"))
    first_cg_tol: float = option(1e-3, real(0, 1, lo_open=True))
    step_cap: float = option(1.0, real(0, lo_open=True))
    guarded: bool = option(True, BOOL)


@register_solver("newton-krylov", NewtonKrylovSettings)
class NewtonKrylovSolver(ReducedSolver):
    """Reduced-space Newton-CG step solver (see the module docstring).

    Parameters
    ----------
    evaluator : StepEvaluator
    settings : NewtonKrylovSettings

    Attributes
    ----------
    iteration_limit : int or None
        The flow's iteration budget of the next solve (set by the flow before each attempt, as for
        IPOPT): a solve still unconverged after this many Newton iterations stops with status
        ``"Iteration_Budget"`` (the same :class:`~willmore_nlp.solvers.ipopt.SolveMonitor` as IPOPT's);
        None: ``max_iter`` only.
    guard_allowed : bool
        Whether the next solve may run the guarded pass (with ``guarded``; set by the flow before each attempt: not
        for a step grown past the last accepted size, which is retried at that size instead).
    """

    def __init__(self, evaluator: StepEvaluator, settings: NewtonKrylovSettings) -> None:
        super().__init__(evaluator, settings, "newton-krylov")
        self.iteration_limit: int | None = None
        self.guard_allowed = True
        self.cg_max_iter = settings.cg_max_iter
        self.precond_move = settings.precond_move
        self.precond_move_indefinite = settings.precond_move_indefinite
        self.cg_rebuild = settings.cg_rebuild
        self.cg_stale = settings.cg_stale
        self.cg_forcing = settings.cg_forcing
        self.max_shift = settings.max_shift
        large = self.nxm // self.P.m > FIRST_SHIFT_VERTICES  # (free vertices)
        self.first_shift = settings.first_shift if settings.first_shift is not None else (
            FIRST_SHIFT_LARGE if large else FIRST_SHIFT)
        self.first_cg_tol = settings.first_cg_tol
        self.step_cap = settings.step_cap
        self.guarded = settings.guarded
        self._jy = SymmetricFactor(settings.cholesky, simplicial=True)  # (N x N: simplicial solves faster)
        self._pre = SymmetricFactor(settings.cholesky)
        self.backend = self._jy.backend
        evaluator.cholesky = self.backend  # the flow's own Y[X] solves: Cholesky of the N x N block as well
        if not np.all(self.P.y_free[self.P.x_free]):
            raise ValueError("newton-krylov needs every free X node to carry a free Y")
        self._times: dict[str, float] = {}
        self._pre_x: np.ndarray | None = None  # free X where B was built, and for which tau
        self._pre_tau = float("nan")
        self._pre_point: tuple[np.ndarray, np.ndarray] = (np.zeros(0), np.zeros(0))  # B's (z, p): warm_state
        self._cg_since_build = 0  # CG iterations with the current B
        self._g0 = 1.0  # size of the first (reduced) gradient of a solve: CG forcing term
        self._gtol = 0.0  # the solve's stopping tolerance on |grad W^|_inf
        self._delta = self._delta_max = 0.0  # shift of the Newton systems
        self.should_stop = lambda: False
        self._edges: np.ndarray | None = None
        self._first_state: tuple[np.ndarray | None, int] = (None, 0)
        self._guard: tuple[np.ndarray, float] | None = None  # guarded pass: X^k's triangle normals, the angle floor

    # -- bookkeeping ------------------------------------------------------------------
    @contextmanager
    def _timed(self, key: str) -> Iterator[None]:
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self._times[key] = self._times.get(key, 0.0) + time.perf_counter() - t0

    # -- J_Y and the point X ----------------------------------------------------------
    def _factor_jy(self, Jy: sp.spmatrix) -> KronFactor | FullFactor:
        """Factorisation of J_Y: of its N x N block (linear inner equation) or of the whole matrix."""
        with self._timed("factor"):
            self._count("n_factorizations")
            if self.P.nonlinear_inner:
                return FullFactor(self._jy.factor(Jy))
            m = self.P.m
            return KronFactor(self._jy.factor(sp.csc_matrix(Jy)[0::m, 0::m]), m)

    def _at(self, x: np.ndarray, p: np.ndarray, Y0: np.ndarray) -> _Point:
        """Y[X] (:meth:`StepEvaluator.inner_solve` with this solver's factorisations), W^, its adjoint
        gradient and the factorised J_Y at the free positions ``x``.

        A linear inner equation has J_Y independent of Y: the last factorisation of the inner solve serves
        the adjoint; a nonlinear one is factorised again at Y[X].
        """
        P = self.P
        last: list[KronFactor | FullFactor] = []

        def linear_solve(Jy: sp.csc_matrix, r: np.ndarray) -> np.ndarray:
            last[:] = [self._factor_jy(Jy)]
            with self._timed("cg"):
                return last[0].solve(r)

        self._count("n_inner_solve")
        _, z, J = self.ev.inner_solve(P.unpack_x(x, P.params.xk(p)), p, Y0, linear_solve=linear_solve)
        self._count("n_eval_jac_g")
        fact = last[0] if last and not P.nonlinear_inner else self._factor_jy(J[:, self.nxm :])
        with self._timed("eval"):
            f, gf = self.ev.f_grad(z, p)
        self._count("n_eval_grad_f")
        return self._point(x, z, f, gf, J, fact, p)

    # -- preconditioner ---------------------------------------------------------------
    def _distance_hessian(self, z: np.ndarray, p: np.ndarray) -> sp.csc_matrix:
        with self._timed("eval"):
            return super()._distance_hessian(z, p)

    def _build_preconditioner(self, pt: _Point, p: np.ndarray, D: sp.csc_matrix) -> None:
        """Factorise B = D + 2 tau K^T Ml^-1 K at ``pt`` (module docstring)."""
        with self._timed("factor"):
            self._pre.factor(self._gauss_newton(pt, p, self.P.params.scalar(p, "tau")).tocsc() + D)
        self._count("n_precond_builds")

    def _rebuild(self, pt: _Point, p: np.ndarray, D: sp.csc_matrix) -> None:
        """Build B at ``pt`` and remember where (and for which tau)."""
        self._build_preconditioner(pt, p, D)
        self._pre_x, self._pre_tau, self._cg_since_build = pt.x.copy(), self.P.params.scalar(p, "tau"), 0
        self._pre_point = (pt.z.copy(), p.copy())

    def warm_state(self) -> dict[str, np.ndarray]:
        """What the next solve takes over from the last one: the point and parameters at which the preconditioner
        B was built and the CG iterations done with it; {} when no B is kept.

        Returns
        -------
        dict with ``z`` (nx,), ``p`` (np,) and ``cg`` (1,) int, or {}
        """
        if self._pre_x is None:
            return {}
        z, p = self._pre_point
        return {"z": z, "p": p, "cg": np.array([self._cg_since_build])}

    def set_warm_state(self, state: dict[str, np.ndarray]) -> None:
        """Rebuild the preconditioner that :meth:`warm_state` described (a resumed run's solver, so that its next
        solve is the uninterrupted one's, bit for bit)."""
        z, p = (np.asarray(state[k], dtype=float) for k in ("z", "p"))
        if z.shape != (self.P.nx,) or p.shape != (self.P.params.size,):
            raise ValueError(f"warm state of shapes {z.shape}, {p.shape} for a step problem of {self.P.nx} unknowns")
        self._rebuild(self._full_point(z, p, np.zeros(self.P.ng)), p, self._distance_hessian(z, p))
        self._cg_since_build = int(np.asarray(state["cg"]).ravel()[0])

    # -- Newton-CG --------------------------------------------------------------------
    def _pcg(self, pt: _Point, p: np.ndarray, D: sp.csc_matrix, delta: float, eta: float,
             max_iter: int) -> tuple[np.ndarray, int, str]:
        """Preconditioned CG on (Hess W^ + delta D) d = -grad; stops at non-positive curvature. With outer
        constraints projected CG in the null space of their reduced Jacobian C (:meth:`_precondition`),
        on the Hessian of the reduced Lagrangian W^ + mu . h^, stopped on the projected residual.

        Returns
        -------
        d : (nX m,) the last iterate
        its : CG iterations
        state : "converged", "negative" (a direction of non-positive curvature was met) or "limit"
            (``max_iter`` reached)
        """
        g = pt.pgrad
        x = np.zeros_like(g)
        r = -g
        s = self._precondition(pt, r)
        d = s.copy()
        rs = float(r @ s)
        gnorm = float(np.linalg.norm(g)) if pt.C is None else np.sqrt(max(rs, 0.0))  # (rs < 0: round-off at rest)
        for k in range(max_iter):
            Ad = self._hessp(pt, p, d)
            if delta:
                Ad = Ad + delta * (D @ d)
            dAd = float(d @ Ad)
            if not dAd > 0:
                return x, k + 1, "negative"
            alpha = rs / dAd
            x += alpha * d
            r -= alpha * Ad
            if pt.C is None and np.linalg.norm(r) <= eta * gnorm:
                return x, k + 1, "converged"
            s = self._precondition(pt, r)
            rs_new = float(r @ s)
            if pt.C is not None and np.sqrt(max(rs_new, 0.0)) <= eta * gnorm:  # projected residual
                return x, k + 1, "converged"
            d = s + (rs_new / rs) * d
            rs = rs_new
        return x, max_iter, "limit"

    def _precondition(self, pt: _Point, r: np.ndarray) -> np.ndarray:
        """B^-1 r; with outer constraints projected onto the null space of C in the B inner product,
        ``s - B^-1 C^T (C B^-1 C^T)^-1 C s`` (the constraint preconditioner of projected CG)."""
        s = self._pre.solve(r)
        if pt.C is None:
            return s
        if getattr(pt, "BC", None) is None:
            pt.BC = self._pre.solve(np.ascontiguousarray(pt.C.T))
            pt.CBC = pt.C @ pt.BC
        return s - pt.BC @ np.linalg.solve(pt.CBC, pt.C @ s)

    def _direction(self, pt: _Point, p: np.ndarray, D: sp.csc_matrix, h: float,
                   first: bool = False) -> tuple[np.ndarray | None, bool]:
        """Newton direction from PCG on (Z^T H Z + delta D) d = -pt.grad, rebuilding B and shifting as needed;
        None when the shift would exceed ``max_shift``. ``first``: the first system of a solve, whose shift
        (when CG meets negative curvature) starts at ``first_shift`` and is solved to ``first_cg_tol``; the
        next system starts unshifted (module docstring).

        Returns
        -------
        d : (nX m,) or None
        shifted : whether d solves a shifted system

        ``pt.H`` (the Lagrangian Hessian at ``pt.z`` with multipliers ``pt.lam``) must be set. Solver state
        across iterations: ``_pre_x`` (where B was built), ``_delta``, ``_g0`` (first gradient size).
        """
        tau = self.P.params.scalar(p, "tau")
        move = self.precond_move if self._delta_max == 0 else self.precond_move_indefinite
        if (self._pre_x is None or self._pre_tau != tau or self._cg_since_build >= self.cg_rebuild
                or np.abs(pt.x - self._pre_x).max() > move * h):
            self._rebuild(pt, p, D)
        if first:  # the preconditioner's state before the first system (a replay from X^0 restores it)
            self._first_state = (self._pre_x, self._cg_since_build)
        gmax = float(np.abs(pt.pgrad).max())
        delta = self._delta / 10 if self._delta >= 1e-3 else 0.0
        rel = float(np.sqrt(gmax / self._g0))  # superlinear forcing
        if rel * gmax <= 10 * self._gtol:  # the step expected to be the last: to 0.1 gtol (the result's accuracy)
            rel = min(rel, 0.1 * self._gtol / gmax)
        for _ in range(12):
            fresh = np.array_equal(pt.x, self._pre_x)
            # a shifted system is only a safeguard, except the first one (its multiplier matters)
            eta = self.first_cg_tol if first and delta else min(0.5 if delta else self.cg_forcing, rel)
            limit = self.cg_max_iter if fresh else self.cg_stale
            capped = self._guard is not None and bool(delta) and not first
            if capped:
                limit = min(limit, GUARD_CG)
            with self._timed("cg"):
                d, k, state = self._pcg(pt, p, D, delta, eta, limit)
            self._count("n_cg", k)
            self._cg_since_build += k
            if capped and state == "limit" and float(pt.pgrad @ d) < 0:  # the truncated direction descends
                break
            if limit < self.cg_max_iter and state == "limit" and not capped:  # B built elsewhere: no preconditioner
                self._rebuild(pt, p, D)
                continue
            if state != "negative":
                break
            top = self.max_shift if self._guard is None else GUARD_SHIFT
            raised = self.first_shift if first and not delta else max(1.0, 10 * delta)
            delta = top if 0 < delta < top < raised else raised  # the cap itself is tried
            if delta > top:
                self._delta_max = delta
                return None, True
        self._delta = 0.0 if first else delta
        self._delta_max = max(self._delta_max, delta)
        return d, bool(delta)

    def solve(self, z0: np.ndarray, p: np.ndarray, lam_g0: np.ndarray | None = None) -> SolveResult:
        """Minimise W^ from the X part of ``z0`` (its Y part warm-starts Y[X]; ``lam_g0`` is not used); numpy's and
        scipy's BLAS on one thread meanwhile (:func:`~willmore_nlp.solvers.cholesky.other_blas_one_thread`). A
        Cholesky factor found not positive definite (the preconditioner or J_Y at an iterate whose triangles
        degenerate: the h = 0.07 double torus of reports/genus2_handles_study.py crashed on one) ends the solve
        unconverged, with the reason, so that the flow retries it like any failed solve; the preconditioner's, in the
        first pass after negative curvature, runs the guarded pass first (module docstring)."""
        with other_blas_one_thread():
            try:
                return self._solve(z0, p)
            except np.linalg.LinAlgError as exc:  # CHOLMOD: a factor not positive definite at a degenerate iterate
                return SolveResult(z=np.asarray(z0, float), f=float("nan"), lam_g=np.zeros(self.P.nc), converged=False,
                                   status=f"factorisation failed ({exc})", iterations=0, stats=dict(self._counts))

    def _solve(self, z0: np.ndarray, p: np.ndarray) -> SolveResult:
        t0 = time.perf_counter()
        self._counts, self._times = {}, {}
        P = self.P
        Xk = P.params.xk(p)
        if self._edges is None:  # the topology is fixed for this solver (its simplices need not cover every node:
            self._edges = unique_edges(P.simplices)  # a co-normal blend's step has only the patch and its ring)
        h = float(np.mean(edge_lengths(Xk, self._edges)))  # mean edge of X^k: the preconditioner's rebuild scale
        with self._timed("eval"):
            scale = float(np.abs(self.ev.grad_f(np.asarray(z0, float), p)).max())
        self._count("n_eval_grad_f")
        symbolic = self._jy.n_symbolic + self._pre.n_symbolic  # (CHOLMOD: once per pattern, kept across solves)
        x0, Y0 = np.asarray(z0[: self.nxm], float), P.unpack_z(z0, Xk)[1]  # (the guarded pass starts there too)
        pt = self._feasible(x0, p, Y0)
        D = self._distance_hessian(pt.z, p)
        # the step's scale: the gradient at its start, but at least that of the distance term for a motion of
        # REST_MOTION h (a flow at exact rest, a flat clamped patch, has a gradient of 0 there: the test was then
        # |grad W^| <= 1e-309, which round-off, 4e-20, never met, and every step failed 7 attempts before IPOPT's)
        scale = max(scale, REST_MOTION * float(np.abs(D.diagonal()).max()) * h, 1e-300)
        gtol = self._gtol = self.tol * scale
        self._g0 = max(float(np.abs(pt.pgrad).max()), 1e-300)
        self._delta = self._delta_max = 0.0
        stats: dict[str, Any] = {}
        z, f, lam, it, status, res = self._iterate(pt, p, D, h, gtol)
        if (self.guarded and self.guard_allowed and self._delta_max > 0 and not P.nh and status.startswith(
                ("reduced Hessian too indefinite", "line search failed", "factorisation failed"))):
            # indefinite and not solved: the guarded pass from the same start (module docstring; not with outer
            # constraints: no full space there)
            self._guard = self._mesh_guard(Xk)
            self._count("n_guarded")
            self._delta = self._delta_max = 0.0
            pt = self._feasible(x0, p, Y0)
            try:  # (its own iterations bounded by max_iter alone: 34-44 on the cone, beyond a first-step budget)
                z, f, lam, it2, status, res = self._iterate(pt, p, D, h, gtol, SolveMonitor(None))
            finally:
                self._guard = None
            it += it2
        stats["n_symbolic"] = self._jy.n_symbolic + self._pre.n_symbolic - symbolic
        stats["iteration"] = "full-space" if self._counts.get("n_full_space") else "reduced"
        stats.update(self._counts)
        stats["newton_iterations"] = it
        for key in ("n_cg", "n_guarded", "n_guard"):
            stats.setdefault(key, 0)
        stats["cholesky"] = self.backend
        stats["blas"] = BLAS if self.backend == "cholmod" else ""
        stats["t_wall_total"] = time.perf_counter() - t0
        for key in ("eval", "factor", "cg"):
            stats[f"t_wall_{key}"] = self._times.get(key, 0.0)
        stats["t_wall_solver"] = stats["t_wall_total"] - stats["t_wall_eval"]
        stats.update(res)
        stats["kkt_residual"] = stats["inf_du"]
        stats["gtol"] = gtol
        stats["delta_max"] = self._delta_max
        return SolveResult(z=z, f=f, lam_g=lam, converged=status == "converged", status=status,
                           iterations=it, stats=stats)

    def _iterate(self, pt: _Point, p: np.ndarray, D: sp.csc_matrix, h: float, gtol: float,
                 monitor: SolveMonitor | None = None,
                 start: int = 0) -> tuple[np.ndarray, float, np.ndarray, int, str, dict[str, float]]:
        """Newton on W^ with Y = Y[X] at every iterate, Armijo line search on W^; from iterate ``start`` with the
        ``monitor`` of the solve when the full-space iteration hands back (it polled the monitor there)."""
        status = "maximum iterations"
        it = start
        handed_back = monitor is not None
        monitor = monitor or SolveMonitor(self.iteration_limit)  # the flow's budget; no constraints left to violate
        P = self.P
        for it in range(start, self.max_iter + 1):
            gmax = float(np.abs(pt.pgrad).max())
            if gmax <= gtol:
                status = "converged"
                break
            if it == self.max_iter:
                break
            if self.should_stop():
                status = "stopped"
                break
            if not (handed_back and it == start) and monitor(pt.f, np.zeros(0)):  # cut after iteration_limit its
                status = monitor.cut
                break
            with self._timed("eval"):
                pt.H = self.ev.hess_lag_operator(pt.z, p, 1.0, pt.lam)  # (half the memory of the mirrored matrix)
            self._count("n_eval_hess")
            first = it == 0 and not P.nh and (self._guard is not None or not P.nonlinear_inner)  # (nonlinear: guarded)
            try:
                d, shifted = self._direction(pt, p, D, h, first)
            except np.linalg.LinAlgError as exc:  # B at an iterate whose triangles degenerate: the pass failed
                status = f"factorisation failed ({exc})"
                break
            if d is None:
                status = f"reduced Hessian too indefinite (shift {self._delta_max:.0e} D > max_shift)"
                break
            if first and (shifted or self._guard is not None):  # indefinite at X^k: SQP from the accurately
                # shifted first step on; the guarded pass also from a positive definite one (module docstring)
                return self._iterate_full(pt, p, D, h, gtol, monitor, d)
            new = self._line_search(pt, p, d)
            if new is None:
                status = f"line search failed (|grad W^| = {gmax:.2e} > {gtol:.2e})"
                break
            pt = new
        with self._timed("eval"):
            inf_pr = float(np.abs(np.concatenate([self.ev.g(pt.z, p), self.ev.h(pt.z, p)])).max())
        return pt.z, pt.f, pt.lam, it, status, {"inf_du": float(np.abs(pt.pgrad).max()), "inf_pr": inf_pr}

    def _line_search(self, pt: _Point, p: np.ndarray, d: np.ndarray) -> _Point | None:
        """Backtracking from the full step: Armijo on W^ (module docstring); None when it fails."""
        gd = float(pt.grad @ d)
        if not gd < 0:
            d, gd = -pt.pgrad, -float(pt.pgrad @ pt.pgrad)
        Y0 = self.P.unpack_z(pt.z, self.P.params.xk(p))[1]
        rounding = 100 * np.finfo(float).eps * abs(pt.f)
        gmax = float(np.abs(pt.pgrad).max())
        alpha = 1.0
        for _ in range(40):
            try:
                new = self._feasible(pt.x + alpha * d, p, Y0)
            except RuntimeError:
                new = None
            if new is not None and np.isfinite(new.f):
                if new.f <= pt.f + self.armijo * alpha * gd:
                    return new
                if -alpha * gd <= rounding and np.abs(new.pgrad).max() < gmax:  # f is rounding noise there
                    return new
            alpha *= 0.5
        return None

    # -- the guarded pass ---------------------------------------------------------------
    def _mesh_guard(self, Xk: np.ndarray) -> tuple[np.ndarray, float]:
        """(triangle normals of X^k, angle floor GUARD_ANGLE x its smallest angle) of a surface in R^3; a curve or a
        surface in another dimension gets no floor (its simplices have no angle here: (empty, -inf))."""
        P = self.P
        if not (P.d == 2 and P.m == 3):
            return np.zeros((0, 3)), -np.inf
        return face_normals(Xk, P.simplices), GUARD_ANGLE * float(geometry.min_angles(Xk, P.simplices).min())

    def _guard_refuses(self, x: np.ndarray, Xk: np.ndarray) -> bool:
        """Whether the free positions ``x`` flip a triangle of X^k or put an angle below the guarded pass's floor."""
        if self._guard is None or not len(self._guard[0]):
            return False
        normals, floor = self._guard
        X = self.P.unpack_x(x, Xk)
        S = self.P.simplices
        flipped = np.einsum("ij,ij->i", face_normals(X, S), normals) <= 0
        return bool(flipped.any()) or float(geometry.min_angles(X, S).min()) < floor

    # -- full-space (SQP) iteration ---------------------------------------------------
    def _full_point(self, z: np.ndarray, p: np.ndarray, lam: np.ndarray) -> _Point:
        """Everything the full-space iteration needs at a (possibly infeasible) z: W, its gradient, g, J,
        the factorised J_Y, the reduced gradient Z^T grad W (:meth:`_point`: adjoint at z) and the Hessian
        multipliers ``lam`` (not the adjoint one)."""
        n = self.nxm
        with self._timed("eval"):
            f, gf = self.ev.f_grad(z, p)
            gv, J = self.ev.g_jac(z, p)
        self._count("n_eval_grad_f")
        self._count("n_eval_jac_g")
        pt = self._point(z[:n], z, f, gf, J, self._factor_jy(J[:, n:]), p)  # the full-space iteration: no h
        pt.lam, pt.gv = lam, gv
        return pt

    def _iterate_full(self, pt: _Point, p: np.ndarray, D: sp.csc_matrix, h: float, gtol: float,
                      monitor: SolveMonitor,
                      d0: np.ndarray) -> tuple[np.ndarray, float, np.ndarray, int, str, dict[str, float]]:
        """Full-space Newton (SQP) on the KKT system of min W s.t. g = 0, each system in reduced form, from the
        feasible first iterate ``pt`` of :meth:`_iterate` (its Hessian ``pt.H`` set, its checks done) and that
        iterate's Newton direction ``d0`` (module docstring)."""
        P, n = self.P, self.nxm
        Xk = P.params.xk(p)
        status = "maximum iterations"
        with self._timed("eval"):
            pt.gv = self.ev.g(pt.z, p)
        rho = 0.0
        it = 0
        pt0 = pt

        def restored(q: _Point) -> _Point:  # the point at q's X with Y = Y[X] (warm-started from q's Y)
            return self._at(q.x, p, P.unpack_z(q.z, Xk)[1])

        def leave(q: _Point) -> _Point:  # hand q to the reduced iteration, the points left behind without their
            # matrices (the callers' frames keep pt and pt0 alive through it: 3 Hessians at once otherwise)
            for old in (pt, pt0):
                old.H = old.Jx = old.Jy = old.lu = None
            return q

        for it in range(self.max_iter + 1):
            gmax = float(np.abs(pt.grad).max())
            if not it:  # iterate 0 was tested and its direction found by _iterate
                with self._timed("cg"):
                    dyp = -pt.lu.solve(pt.gv)
                d: np.ndarray | None = d0
            else:
                if gmax <= gtol:  # final test at the restored point Y = Y[X] (the reduced iteration's test)
                    q = restored(pt)
                    self._count("n_restoration")
                    with self._timed("eval"):
                        q.gv = self.ev.g(q.z, p)
                    if float(np.abs(q.pgrad).max()) <= gtol:
                        pt = q
                        status = "converged"
                        break
                    q.lam = pt.lam
                    pt = q
                if it == self.max_iter:
                    break
                if self.should_stop():
                    status = "stopped"
                    break
                if monitor(pt.f, pt.gv):
                    status = monitor.cut
                    break
                with self._timed("eval"):
                    pt.H = self.ev.hess_lag_operator(pt.z, p, 1.0, pt.lam)
                self._count("n_eval_hess")
                with self._timed("cg"):
                    dyp = -pt.lu.solve(pt.gv)
                    v = pt.gf + pt.H @ np.concatenate([np.zeros(n), dyp])
                    pt.pgrad = v[:n] + pt.Jx.T @ pt.lu.solve(-v[n:], trans="T")  # Z^T (grad W + H dz_p)
                d, shifted = self._direction(pt, p, D, h)
                # (the guarded pass stays in the full space: neither exit below)
                if shifted and self._guard is None and it >= HANDBACK_AFTER:  # negative curvature again after
                    # full-space progress: the reduced iteration goes on from here, Y = Y[X] (40,962-v sphere: 13
                    # Newton iterations where the restart from X^0 below took 22)
                    q = restored(pt)
                    self._count("n_restoration")
                    self._count("n_handback")
                    return self._iterate(leave(q), p, D, h, gtol, monitor, it)
                if shifted and self._guard is None:  # negative curvature again at once: the first multiplier did
                    # not help. The reduced iteration from X^0 with the preconditioner's state of the start: its path
                    # as without the full-space attempt, two iterations later
                    pre_x, cg = self._first_state
                    if self._pre_x is pre_x:
                        self._cg_since_build = cg
                    else:
                        self._rebuild(pt0, p, D)
                    self._delta = 0.0
                    self._count("n_replay")  # (J_Y's factorisation is refactorised in place: X^0 evaluated again)
                    return self._iterate(leave(restored(pt0)), p, D, h, gtol, monitor, it)
            if d is None:
                status = f"reduced Hessian too indefinite (shift {self._delta_max:.0e} D > max_shift)"
                break
            dz, Hdz, lam_new = self._kkt_step(pt, d, dyp)
            cap = self.step_cap if self._guard is None else GUARD_STEP
            new = self._merit_search(pt, p, dz, Hdz, lam_new, rho, min(1.0, cap * h / np.abs(d).max()))
            if new is None:
                why = ("line search failed" if self._counts.get("n_guard", 0) < GUARD_REFUSALS else
                       f"guarded pass: the mesh guard refused {GUARD_REFUSALS} trial points")
                status = f"{why} (|grad W^| = {gmax:.2e} > {gtol:.2e})"
                break
            pt, rho = new
            self._count("n_full_space")  # Newton iterations of the full-space iteration
        with self._timed("eval"):
            inf_pr = float(np.abs(self.ev.g(pt.z, p)).max())
        return pt.z, pt.f, pt.lam, it, status, {"inf_du": float(np.abs(pt.pgrad).max()), "inf_pr": inf_pr}

    def _kkt_step(self, pt: _Point, d: np.ndarray, dyp: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The KKT step from the X step ``d`` ((nX m,), from the reduced system) at ``pt`` (``pt.H``, ``pt.gf`` set):
        dz = (d, dyp - J_Y^-1 J_X d) ((nx,), ``dyp`` = -J_Y^-1 g the step onto g = 0), H dz, and the new multiplier
        lam+ = -J_Y^-T (f_Y + (H dz)_Y) ((ng,)): the Y rows of the KKT system (a shift in X leaves them as they are).
        """
        n = self.nxm
        with self._timed("cg"):
            dz = np.concatenate([d, dyp - pt.lu.solve(pt.Jx @ d)])
            Hdz = pt.H @ dz
            lam_new = pt.lu.solve(-(pt.gf[n:] + Hdz[n:]), trans="T")
        self._count("n_linear_solves", 2)
        return dz, Hdz, lam_new

    def _merit_search(self, pt: _Point, p: np.ndarray, dz: np.ndarray, Hdz: np.ndarray, lam_new: np.ndarray,
                      rho: float, alpha: float) -> tuple[_Point, float] | None:
        """Backtracking from ``alpha`` (the step cap) on the augmented Lagrangian W + lam . g + rho/2 |g|^2 along
        (dz, lam_new - lam), with a second-order correction (Y = Y[X]) of the full step."""
        n = self.nxm
        P = self.P
        g, lam = pt.gv, pt.lam
        gdz = float(pt.gf @ dz)
        gg = float(g @ g)
        curv = max(float(dz @ Hdz), 0.0)
        slope = gdz + float((lam_new - 2 * lam) @ g)  # the slope without the rho term
        if gg > 0 and slope - rho * gg > -0.5 * curv:
            rho = max(rho, 2 * (slope + 0.5 * curv) / gg)
        dphi = slope - rho * gg
        phi0 = pt.f + float(lam @ g) + 0.5 * rho * gg
        if not dphi < 0:
            return None
        rounding = 100 * np.finfo(float).eps * max(abs(pt.f), abs(phi0))
        gmax = float(np.abs(pt.grad).max())
        Xk = P.params.xk(p)
        for _ in range(40):
            zt = pt.z + alpha * dz
            lt = lam + alpha * (lam_new - lam)
            if self._guard_refuses(zt[:n], Xk):  # the guarded pass: a flipped or crushed triangle, a shorter step
                self._count("n_guard")
                if self._counts["n_guard"] >= GUARD_REFUSALS:
                    return None
                alpha *= 0.5
                continue
            with self._timed("eval"):
                ft, gt = self.ev.f(zt, p), self.ev.g(zt, p)
            phi = ft + float(lt @ gt) + 0.5 * rho * float(gt @ gt)
            if np.isfinite(phi) and phi <= phi0 + self.armijo * alpha * dphi:
                return self._full_point(zt, p, lt), rho
            if alpha == 1.0:  # second-order correction: Y = Y[X] at the full step's X
                try:
                    q = self._at(zt[:n], p, P.unpack_z(zt, Xk)[1])
                except RuntimeError:
                    q = None
                self._count("n_soc")
                if q is not None and np.isfinite(q.f):
                    with self._timed("eval"):
                        q.gv = self.ev.g(q.z, p)
                    if q.f + float(lt @ q.gv) + 0.5 * rho * float(q.gv @ q.gv) <= phi0 + self.armijo * dphi:
                        q.lam = lt
                        return q, rho
            if -alpha * dphi <= rounding and np.isfinite(phi):
                q = self._full_point(zt, p, lt)
                if float(np.abs(q.grad).max()) < gmax:
                    return q, rho
            alpha *= 0.5
        return None
