"""Typed settings: every option once, with its default, its allowed values and its meaning.

An option is a field of a frozen dataclass declared with :func:`option` (default and :class:`Kind`);
its meaning is the class docstring's entry. :class:`Settings` validates every field on construction
(one message per option: ``NAME must be WHAT, got VALUE``), reads command-line strings
(:meth:`Settings.parse`) and refuses unknown keys (:meth:`Settings.split`). The flow's options are
:class:`FlowSettings`; each solver declares its own (:mod:`willmore_nlp.solvers`). The Python API
(``WillmoreFlow`` keywords), TOML configs, ``--set`` and ``compare --option`` all go through them, and
``docs/reference/options.md`` is generated from them. Adding an option is one field.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from willmore_nlp.errors import UserInputError
from willmore_nlp.tangential import CONTROL_METHODS


def is_number(v: Any) -> bool:
    """A real number (int, float or a numpy scalar such as ``np.float32(0.01)``), not a bool."""
    return isinstance(v, numbers.Real) and not isinstance(v, (bool, np.bool_))


def auto(v: Any) -> Any:
    """A command-line string read as bool, int or float when it looks like one (else kept)."""
    if not isinstance(v, str):
        return v
    low = v.strip().lower()
    if low in ("true", "false"):
        return low == "true"
    for conv in (int, float):
        try:
            return conv(v)
        except ValueError:
            continue
    return v


def parse_bool(v: Any) -> Any:
    """A command-line string read as a bool (1/0, true/false, yes/no, on/off); anything else is kept."""
    words = {"1": True, "true": True, "yes": True, "on": True, "0": False, "false": False, "no": False, "off": False}
    return words.get(v.strip().lower(), v) if isinstance(v, str) else v


@dataclass(frozen=True)
class Kind:
    """The allowed values of an option.

    Attributes
    ----------
    what : the allowed values in words, completing "NAME must be ..."
    ok : test of a value
    convert : normalises an accepted value (``2.0 -> 2`` for integers, ``3 -> 3.0`` for reals)
    parse : reads a command-line string (values of other types are passed on unchanged)
    choices : the allowed strings of :func:`one_of`
    """

    what: str
    ok: Callable[[Any], bool]
    convert: Callable[[Any], Any] = lambda v: v
    parse: Callable[[Any], Any] = auto
    choices: tuple[str, ...] = ()


MAX_TANGENTIAL_WEIGHT = 1e8
"""Largest ``tangential_weight``: measured on icosphere(2) (tau = 0.01, tau_tilde = 1e-4), weights 1.5 to 1e8 take the
first step without a retry, 1e10 and 1e12 fail every attempt (IPOPT: Search_Direction_Becomes_Too_Small; the normal
motion is lost to round-off beside the tangential term)."""


def real(lo: float = -math.inf, hi: float = math.inf, *, lo_open: bool = False, hi_open: bool = True,
         finite: bool = True, unset: str | None = None, note: str = "") -> Kind:
    """A number in [lo, hi) (bounds open or closed); ``unset``: None allowed, meaning what is said."""
    if hi < math.inf:
        what = f"a number in {'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"
    else:
        # (unbounded: "a finite number", as the vesicle problem's c0 said where the flow's said "a number, got inf")
        what = f"a number {'>' if lo_open else '>='} {lo:g}" if lo > -math.inf else ("a finite number" if finite
                                                                                   else "a number")
    what += f" or unset ({unset})" if unset else ""
    what += f" ({note})" if note else ""

    def ok(v: Any) -> bool:
        if v is None:
            return unset is not None
        return (is_number(v) and (math.isfinite(v) or not finite) and (lo < v if lo_open else lo <= v)
                and (v < hi if hi_open and hi < math.inf else v <= hi))

    return Kind(what, ok, lambda v: None if v is None else float(v))


def integer(lo: int, note: str = "") -> Kind:
    """An integer >= lo (an integral float such as 2.0 is accepted)."""
    return Kind(f"an integer >= {lo}" + (f" ({note})" if note else ""),
                lambda v: is_number(v) and math.isfinite(v) and float(v).is_integer() and v >= lo, int)


def one_of(*choices: str) -> Kind:
    """One of the given strings."""
    return Kind(" or ".join(map(repr, choices)) if len(choices) < 3 else "one of " + ", ".join(map(repr, choices)),
                lambda v: v in choices, parse=lambda v: v, choices=choices)


BOOL = Kind("true or false", lambda v: isinstance(v, bool), parse=parse_bool)
BOOL_OR_UNSET = Kind("true, false or unset", lambda v: v is None or isinstance(v, bool), parse=parse_bool)
ANY = Kind("any value", lambda v: True)
TARGET = Kind("'initial', a number > 0 or unset",
              lambda v: v is None or v == "initial" or (is_number(v) and math.isfinite(v) and v > 0),
              lambda v: v if v is None or isinstance(v, str) else float(v))


def option(default: Any, kind: Kind) -> Any:
    """A settings field: its default and allowed values (its meaning is the class docstring's entry)."""
    return dataclasses.field(default=default, metadata={"kind": kind})


class Settings:
    """Base of the frozen settings dataclasses: validation on construction, string parsing, key splitting.

    :meth:`prefix` starts every message (``"solver sqp: option "``; empty for the flow's options).
    ``renamed`` maps old option names, still accepted (scripts and run directories written before), to new ones.
    """

    renamed: ClassVar[dict[str, str]] = {}

    @classmethod
    def prefix(cls) -> str:
        """What a message starts with."""
        return ""

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):  # type: ignore[arg-type]
            object.__setattr__(self, f.name, self.check(f.name, getattr(self, f.name)))

    @classmethod
    def kinds(cls) -> dict[str, Kind]:
        """Option name -> its :class:`Kind`, in declaration order."""
        return {f.name: f.metadata["kind"] for f in dataclasses.fields(cls)}  # type: ignore[arg-type]

    @classmethod
    def defaults(cls) -> dict[str, Any]:
        """Option name -> default."""
        return {f.name: f.default for f in dataclasses.fields(cls)}  # type: ignore[arg-type]

    @classmethod
    def check(cls, name: str, value: Any) -> Any:
        """``value`` of option ``name`` normalised, or UserInputError ``NAME must be WHAT, got VALUE``."""
        kind = cls.kinds()[name]
        if not kind.ok(value):
            raise UserInputError(f"{cls.prefix()}{name} must be {kind.what}, got {value!r}")
        return kind.convert(value)

    @classmethod
    def parse(cls, name: str, value: Any) -> Any:
        """Option ``name`` from a command-line string (other values unchanged), validated."""
        return cls.check(name, cls.kinds()[name].parse(value))

    @classmethod
    def split(cls, options: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
        """``options`` (old names renamed) split into (this class's options, the others)."""
        kinds = cls.kinds()
        options = {cls.renamed.get(k, k): v for k, v in options.items()}
        return ({k: v for k, v in options.items() if k in kinds}, {k: v for k, v in options.items() if k not in kinds})


SOLVER_IGNORED = ("warm_start", "print_level")
"""Options meant for IPOPT that every other solver accepts and ignores (a config may switch solvers)."""


def flatten_ipopt(options: dict[str, Any]) -> dict[str, Any]:
    """``options`` with an ``ipopt`` mapping (the API's counterpart of a config's ``[ipopt]`` table) given as
    ``ipopt.NAME`` entries: IPOPT's options (:func:`solver_of`).

    Raises
    ------
    UserInputError
        ``ipopt`` is not a mapping, or one of its entries is given as ``ipopt.NAME`` too.
    """
    if "ipopt" not in options:
        return options
    table = options["ipopt"]
    if not isinstance(table, Mapping):
        raise UserInputError(f"ipopt must be a mapping of IPOPT options (name: value), got {table!r}")
    flat = {k: v for k, v in options.items() if k != "ipopt"}
    for k, v in table.items():
        if f"ipopt.{k}" in flat:
            raise UserInputError(f"ipopt: option {k} is given twice, in the ipopt mapping and as ipopt.{k}")
        flat[f"ipopt.{k}"] = v
    return flat


SOLVER_ROLES = ("solver", "first_step_solver", "fallback_solver", "large_solver")
"""The flow options that name a solver of the flow (:class:`FlowSettings`)."""


def flow_solvers(roles: Mapping[str, Any]) -> dict[str, str]:
    """Each of :data:`SOLVER_ROLES` -> the solver ``roles`` (flow options) give it ('' none; ``solver``: "ipopt"
    unless given)."""
    return {r: str(roles.get(r) or ("ipopt" if r == "solver" else "")) for r in SOLVER_ROLES}


def solver_prefix(key: str) -> str:
    """NAME of an option written ``NAME.KEY`` with NAME a registered solver (``ipopt.max_iter``), else ''."""
    from willmore_nlp.solvers import solver_names  # (the solvers' registry imports this module)

    name, dot, _ = key.partition(".")
    return name if dot and name in solver_names() else ""


def solver_of(key: str, roles: Mapping[str, Any]) -> tuple[str, str]:
    """The solver that the solver option ``key`` of a flow is given to, and the option's name there.

    ``NAME.KEY``, NAME a registered solver, is solver NAME's option KEY, whether NAME is the flow's ``solver``,
    ``first_step_solver``, ``fallback_solver`` or ``large_solver`` (``ipopt.max_iter``: a config's ``[ipopt]``
    table and the API's ``ipopt={...}`` give IPOPT's options so); any other key is ``solver``'s. Until 2026-11-30 an
    ``ipopt.NAME`` key counted as ``NAME`` of whichever solver was ``solver``: ``[ipopt] max_iter = 100`` became
    newton-krylov's ``max_iter`` beside an IPOPT fallback, which could not be tuned (a new-user check).

    Parameters
    ----------
    key : a solver option as given
    roles : the flow's :data:`SOLVER_ROLES` (missing or '': none; ``solver`` "ipopt" when missing)

    Raises
    ------
    UserInputError
        NAME is not a solver of the flow: ``KEY: IPOPT is not used (solver S, fallback_solver F)``.
    """
    used = flow_solvers(roles)
    name = solver_prefix(key)
    if not name:
        return used["solver"], key
    if name not in used.values():
        what = "IPOPT" if name == "ipopt" else f"solver {name}"
        given = ", ".join(f"{r} {n or 'none'}" for r, n in used.items() if n or r == "fallback_solver")
        raise UserInputError(f"{key}: {what} is not used ({given}): add --set fallback_solver={name} or "
                             f"solver={name} (fallback_solver={name!r} in Python), or leave {key} out")
    return name, key.removeprefix(f"{name}.")


def route_solver_options(options: Mapping[str, Any], roles: Mapping[str, Any]) -> dict[str, dict[str, Any]]:
    """Solver name -> its options, for every solver of a flow (:data:`SOLVER_ROLES` ``roles``), each key given as it
    is (``NAME.KEY`` or ``KEY``, which :meth:`SolverSettings.from_options` both take) to the solver :func:`solver_of`
    says.

    Raises
    ------
    UserInputError
        As :func:`solver_of`, or an option given twice to one solver (``max_iter`` and ``ipopt.max_iter`` with
        ``solver = "ipopt"``).
    """
    out: dict[str, dict[str, Any]] = {n: {} for n in flow_solvers(roles).values() if n}
    given: dict[tuple[str, str], str] = {}
    for key, value in options.items():
        name, option_name = solver_of(key, roles)
        if (name, option_name) in given:
            raise UserInputError(f"option {option_name} of solver {name} is given twice, as {given[name, option_name]} "
                                 f"and as {key}")
        given[name, option_name] = key
        out[name][key] = value
    return out


class SolverSettings(Settings):
    """Options of one solver: ``from_options`` refuses keys it neither declares nor ``ignores``."""

    solver: ClassVar[str] = ""
    ignores: ClassVar[tuple[str, ...]] = SOLVER_IGNORED

    @classmethod
    def prefix(cls) -> str:
        """``solver NAME: option ``."""
        return f"solver {cls.solver}: option "

    @classmethod
    def config_keys(cls) -> tuple[str, ...]:
        """The keys a config may give for this solver (besides ``NAME.KEY``, :func:`solver_of`)."""
        return tuple(cls.kinds())

    @classmethod
    def owns(cls, key: str) -> bool:
        """Whether ``key`` (or its old name) is an option of this solver."""
        return cls.renamed.get(key, key) in cls.kinds()

    @classmethod
    def refuse_others(cls, keys: Iterable[str]) -> None:
        """Refuse the first of ``keys`` (not options of this solver) that is an option of another solver.

        Raises
        ------
        UserInputError
            ``KEY is an option of solver OTHER, not of NAME: add --set solver=OTHER ...``.
        """
        from willmore_nlp.solvers import solver_names, solver_settings  # (the solvers' registry imports this module)

        for key in keys:
            owners = [n for n in solver_names() if n != cls.solver and solver_settings(n).owns(key)]
            if owners:
                one = len(owners) == 1
                which, name = (f"solver {owners[0]}", owners[0]) if one else (f"solvers {', '.join(owners)}", "NAME")
                raise UserInputError(f"{key} is an option of {which}, not of {cls.solver}: add --set solver={name}"
                                     f"{'' if one else ' with one of them'} (solver={name!r} in Python)")

    @classmethod
    def from_options(cls, options: dict[str, Any]) -> SolverSettings:
        """Validated settings from a dict of options, each written ``KEY`` or ``NAME.KEY`` (NAME this solver's name;
        a flow's options are routed by :func:`solver_of`).

        Raises
        ------
        UserInputError
            ``KEY is an option of solver OTHER, not of NAME ...``, ``solver NAME: unknown option(s) ...; known:
            ...`` or ``solver NAME: option KEY must be ...``.
        """
        mine, other = cls.split({k.removeprefix(f"{cls.solver}."): v for k, v in options.items()})
        unknown = sorted(set(other) - set(cls.ignores))
        cls.refuse_others(unknown)
        if unknown:
            known = ", ".join(cls.kinds()) or "none"
            raise UserInputError(f"solver {cls.solver}: unknown option(s) {', '.join(unknown)}; known: {known}")
        return cls(**mine)


RUN_KINDS: dict[str, Kind] = {
    "tau": real(0, lo_open=True),
    "tau_tilde": real(0, lo_open=True),
    "lam": real(0),
    "steps": integer(1),
    "t_end": real(0, lo_open=True),
}
"""Step sizes, length/area weight and run length (problem parameters and ``WillmoreFlow`` arguments)."""


def check_run_value(name: str, value: Any) -> Any:
    """A :data:`RUN_KINDS` value, normalised, or UserInputError ``NAME must be WHAT, got VALUE``."""
    if not RUN_KINDS[name].ok(value):
        raise UserInputError(f"{name} must be {RUN_KINDS[name].what}, got {value!r}")
    return RUN_KINDS[name].convert(value)


def moebius_invariant(lam: float, c0: float, anisotropy: Any, volume: Any = None, area: Any = None) -> bool:
    """Whether the step's energy of a closed surface is the Willmore energy alone, invariant under the Moebius group
    (no length/area weight ``lam``, spontaneous curvature ``c0``, anisotropy or volume/area constraint), so that the
    ten conformal fields are its zero modes: where the conformal gauge and the drift rule may act."""
    return lam == 0 and c0 == 0 and anisotropy is None and volume is None and area is None


@dataclass(frozen=True)
class FlowSettings(Settings):
    """The options of :class:`~willmore_nlp.flow.WillmoreFlow` (keywords, config keys, ``--set KEY=VALUE``).

    Solver options (``tol``, ``max_iter``, ``warm_start``, IPOPT's) are the solver's own
    (:func:`willmore_nlp.solvers.solver_settings`).

    Attributes
    ----------
    solver : str
        Registered solver name (``"ipopt"`` default).
    first_step_solver : str
        The solver of the run's first step when it is not ``solver`` ("" default: ``solver``); every later step,
        and a resumed run's steps after the first, use ``solver``. "ipopt" with ``solver = "newton-krylov"``
        starts a flow with IPOPT's first step (measured: docs/guide/performance.md). Options written ``NAME.KEY``
        (``ipopt.max_iter``, a config's ``[ipopt]`` table) are solver NAME's, whichever of ``solver``,
        ``first_step_solver``, ``fallback_solver`` and ``large_solver`` it is (an error when it is none of them), the
        others ``solver``'s; only ``solver``'s iteration counts enter the iteration budget.
    fallback_solver : str
        A solver that takes a step over when every attempt of ``solver`` (``max_retries`` halvings of tau) failed:
        its attempts start again from the step's first tau ("" default: none, the step fails). The ``file``
        problem's default for surfaces of 500 vertices or more is ``solver = "newton-krylov"`` with
        ``fallback_solver = "ipopt"``: newton-krylov fails the first step of some noisy inputs at every tau (its
        reduced Hessian too indefinite), IPOPT takes it, and newton-krylov is several times faster on the steps it
        takes (docs/guide/performance.md). The rejected attempts then name their solver.
    large_solver : str
        The solver of the steps that start on a mesh of at least ``large_vertices`` vertices ("" default: none,
        ``solver`` throughout), with ``fallback_solver`` or else ``solver`` as its fallback: a run that a remeshing
        (``refine_dihedral``) grows past that size changes solver at the next step, and a resumed run chooses the
        same from its state. Its options, when it is not ``solver``, are written ``NAME.KEY``
        (``newton-krylov.cholesky`` in Python; ``ipopt.KEY`` also in configs and ``--set``). The ``file`` problem's
        surfaces whose flow starts below 500 vertices, and the other problems' below 10,000, get ``large_solver =
        "newton-krylov"`` from those sizes when no solver is named (a double torus refined from 453 to 6,339
        vertices had gone on with IPOPT: docs/guide/performance.md).
    large_vertices : int
        The size from which ``large_solver`` takes the steps (vertices of the mesh a step starts from; 0 default).
    codegen : bool or None
        Compile the element kernels to C and cache the library (:mod:`willmore_nlp.codegen`).
        None (default): when a C compiler is found, else CasADi's virtual machine with a warning.
    max_retries : int
        How many times a failed step is retried with tau halved.
    check_energy : bool
        Reject steps that violate the discrete energy inequality W(X^{k+1}) <= W(X^k) = 2 tau e(X^k).
    min_angle : float
        Reject surface steps whose smallest triangle angle (degrees) drops below this.
    max_edge_ratio : float
        Reject steps whose longest/shortest edge ratio exceeds this.
    max_dihedral : float
        Reject surface steps (in R^3) that fold the mesh: a step after which the normals of the two triangles at an
        edge turn by more than this angle (degrees) and by more than at the step's start (an edge already that sharp
        in X^k, a box's, may stay so). 180 switches the check off. Triangles of good shape can fold flat onto each
        other, which the angle and edge-ratio checks do not see (docs/guide/mesh_quality.md, "Folds").
    refine_dihedral : float
        While ``remesh`` is on (surfaces in R^3): after a step that sharpens an edge past this angle between the
        normals of its two triangles (degrees; default 75; 180: off), the region around such edges
        (``refine_local``; false: the whole mesh, toward its edge divided by sqrt 2, about twice the
        vertices) is remeshed finer (the history action "refine", a warning), kept when its
        sharpest edge turns by less than the stepped state's, with ``tau_tilde`` following h^2 when
        ``steps_from_h`` names it. Such edges are where the mesh stops resolving the surface (a bar between two
        holes of a genus-2 flow narrowing to a tube a few edges round), and where it would fold next; refined
        later (at 100 degrees) the remeshing makes that edge sharper still (docs/guide/mesh_quality.md, "Folds").
        In the runs of the built-in surface problems measured on 2026-11-29 (60 or 200 steps each, the 48 x 24 torus
        to t = 1) no edge got sharper than 58.3 degrees; the ``torus`` problem's own default run (24 x 12, 100 steps to
        t = 0.1) is refined once, at step 65 (276 -> 328 vertices), its sharpest edge at 74.5 degrees and W at 37.60,
        below the smooth minimum 4 pi^2 = 39.48 on that coarse mesh; it ends at W 38.69 with the sharpest edge at 53
        degrees (2026-12-03, a new user's check).
    refine_max_vertices : int
        No refinement (``refine_dihedral``) past this many vertices (default 50,000).
    refine_local : bool
        Default true: a refinement remeshes only the region of the edges sharper than 0.6 ``refine_dihedral`` that
        have a triangle with a free vertex (on a clamped surface: the clamped part's own creases are not the patch's
        to resolve) and two rings of triangles around them (its rim fixed; on a clamped surface its free vertices
        only), toward the edge of the triangles at those edges divided by sqrt 2, and ``tau_tilde`` (when it follows
        h) is halved; a state whose repairs sharpen an edge past ``refine_dihedral`` is refined too. Once the mesh is
        graded so, a threshold remeshing remeshes only the triangles below ``remesh_min_angle`` and two rings around
        them, toward the edge of those triangles, and ``remesh_max_edge_ratio`` applies within each triangle. False:
        the whole mesh (the patch of a clamped surface) (docs/guide/mesh_quality.md, "Local refinement").
    energy_rtol : float
        Relative slack of the energy check: a step passes when W <= W(X^k) (1 + energy_rtol) + 1e-14.
    allow_components : bool
        Accept a mesh of several separate curves or surfaces (default: one is expected,
        :func:`willmore_nlp.mesh.topology.check_connected`).
    anisotropy : str, callable or Anisotropy, optional
        Anisotropy gamma for the fully nonlinear anisotropic scheme (paper Secs. 2.3, 3.3): a
        preset name ("gamma0", "gamma1", "gamma2"), a 1-homogeneous gamma(z) written with CasADi
        operations, or an :class:`~willmore_nlp.anisotropy.Anisotropy`. Closed curves in R^2 and
        closed surfaces in R^3; the inner equation is then nonlinear in Y (damped Newton). Each
        StepResult reports the anisotropic Willmore energy ``willmore_gamma``.
    tangential_weight : float
        beta >= 1 (default 1, the paper's scheme): the distance term of W charges the tangential
        part of X - X^k beta times (:class:`willmore_nlp.model.terms.distance.Distance`). The normal
        motion, and so the geometric flow as h -> 0, is unchanged; nodes stop sliding to where the
        discrete energy rewards them (needed for the nearly crystalline gamma2, e.g. beta = 1000). At most
        :data:`MAX_TANGENTIAL_WEIGHT`.
    c0 : float
        Spontaneous curvature (Canham-Helfrich, default 0): the flow of ``1/2 int (h - c0)^2`` with
        h = k1 + k2 (> 0 on a sphere with the outward normal), closed curves in R^2 and closed
        surfaces in R^3 (:mod:`willmore_nlp.model.terms.helfrich`). 0 is the Willmore flow bit for bit.
    volume : "initial", float or None
        Keep the enclosed volume (area of a closed curve in R^2) at this value, or at the initial
        mesh's (``"initial"``): an outer equality constraint of every step (solvers ipopt, sqp, gd,
        newton-krylov). The solver's residual (``stats["constraint_violation_solver"]``, relative;
        measured <= 4e-11) is then removed by least-norm Gauss-Newton steps, so every accepted state
        holds the constraint to 1e-13; a residual above 1e-6 rejects the step. None (default): free. A
        target other than the initial value first moves the initial mesh onto it the same way, as after
        every mesh repair.
    area : "initial", float or None
        Likewise for the total area (length of a closed curve). Both held: targets beyond the isoperimetric
        inequality 36 pi V^2 <= A^3 (4 pi A <= L^2 of a closed curve), which no mesh reaches, are refused.
    tangential_control : str
        Tangential motion inside the step (:mod:`willmore_nlp.tangential`): "auto" (default), "off" (the paper's
        scheme) or "meanratio". "auto" is "meanratio" for surfaces in R^3 that are clamped, open or of genus 0,
        whose initial mesh has a tangent plane at every moving node, when ``mesh_control`` is "auto" and the
        solver minimises W (not the semi-implicit baseline), else "off" (curves, meshes with sharp edges or
        spikes and unclamped closed surfaces of genus >= 1 keep the paper's scheme;
        :func:`willmore_nlp.tangential.resolve_method`). "meanratio": W gains ``beta_c sum_i m_i |P_i
        (X_i-X^k_i-S_i)|^2`` with P_i the vertex tangent projector of X^k and S_i the tangential part of a
        mean-ratio mesh-improving step of X^k, so that the nodes follow a mesh-improving tangential motion while
        the normal component of every nodal equation, hence the geometric flow as h -> 0, is unchanged. Fixed
        (boundary) nodes never move. The discrete energy may rise by at most ``beta_c sum_i m_i |S_i|^2 / (2
        tau)`` in a step (the energy check uses the full W).
    tangential_control_weight : float or None
        beta_c > 0 of the mean-ratio control: the tangential motion is about beta_c / (1 + beta_c) of S plus
        1 / (1 + beta_c) of what the energy asks for. None (default): 1 (measured:
        docs/guide/mesh_quality_measurements.md, "Rest means rest"), and 100 on a clamped surface with an
        anisotropy, whose first free row slides toward the clamp under a smaller weight (docs/guide/anisotropy.md;
        :func:`willmore_nlp.tangential.default_weight`).
    tangential_control_time : float
        T_c >= 0: a step of size tau targets the fraction min(1, tau / T_c) of the mesh-improving
        step (a tangential velocity of at most 1/T_c steps per unit time, consistent as tau -> 0);
        0 (default) targets the whole step every time.
    redistribute : bool
        Closed curves only: after every accepted step move the vertices along the curve to equal
        arc-length spacing (:func:`willmore_nlp.geometry.redistribute_curve`) and solve Y[X] again.
        Not part of the paper's scheme: it changes the curve by O(h^2 kappa) and the energy e(X)
        by a little (``stats["energy_before_redistribution"]`` and ``stats["redistribution_shift"]``
        record it), so e(X^k) is no longer guaranteed to decrease from step to step.
    adaptive : bool
        Step-size control for stiff starts: a step first tries twice the previous accepted step
        (the same step if that one needed retries), never more than ``tau``; failures halve it as
        usual (``max_retries`` per step). After a step that needed retries the doubling waits 2, 4,
        8, ... steps (the wait doubles with each such step and ends when a doubled step succeeds), so
        a flow whose steps cannot grow does not spend every other attempt trying; at most
        ``adaptive_max_wait`` steps. Off, every step first tries ``tau``. Default for surfaces read by the
        ``file`` problem.
    adaptive_max_wait : int
        Longest wait of ``adaptive`` (and ``relax``) steps before the next doubling (default 64; 0: no limit, the rule
        before 2026-11-30 and of run directories written before it). Without it a flow with ten steps that needed
        retries early waited 1,024 steps: a double torus read from a file (839 vertices, its defaults) held tau at
        2.7e-4, tau / 4,100, from step 54 to step 300 without a single retry, and reached t = 0.517 where Lawson's
        energy needs about t = 1.
    convex_start : bool
        With ``adaptive`` or ``relax`` steps: when the first two attempts of a run's first step (at tau and tau / 2)
        fail, the next one is taken below the step size tau_c at which the step problem stops being convex at the
        initial state (:func:`willmore_nlp.solvers.reduced.convexity_limit`): at the largest tau / 2^j not above tau_c /
        2 (tau_c when that is below ``min_tau``) instead of at tau / 4, when tau_c < tau / 16 (``flow.CONVEX_JUMP``:
        beyond the default four halvings), and already before newton-krylov's first attempt (after IPOPT's or another
        solver's first failure) when a first, cheap Lanczos look finds tau_c < tau / 10^5 (``flow.CONVEX_FAR``); the
        adaptive steps then grow from there (a warning names it). The first step after a refinement
        (``refine_dihedral``), a new discretisation, is treated as a first step. A noisy input's step problem is convex
        only below tau / 10^3 - tau / 10^7 (its noise is smoothed on that time scale, about 0.01-0.04 h^4): its first
        step at tau / 2^j is a non-convex problem that the solvers took after several failed attempts or not at all,
        where from tau_c the steps converge at their first attempt in 4-9 Newton iterations while tau doubles
        (docs/guide/mesh_quality.md, "Below the convexity limit"). With a volume or area constraint tau_c is that of the
        step problem without them, a lower bound, and only the last attempt (``max_retries``) goes below it, with no
        first look (docs/guide/terms.md, "Volume and area of closed surfaces"). A first step taken at tau or tau / 2,
        and every smooth input, are unchanged (the first look costs 0.1-10 s: on newton-krylov's first step, on other
        solvers' where a first attempt failed). A flow with fixed steps keeps them; when one of its steps fails because
        its solvers did not converge, the error names tau_c there (and ``tau = tau_c / 2`` or ``adaptive = true`` as
        the ways on). Default true.
    min_tau : float, optional
        Floor of the step size: a step whose next attempt would be below ``min(min_tau, tau)``
        fails (FlowError, status "failed") instead of freezing the clock. Default 1e-2 h^4
        (h = initial mean edge): below the paper's smallest step h^4 by more than the four
        default halvings, and so small that reaching t = O(1) would take > 100 h^-4 steps. Each
        refinement (``refine_dihedral``) divides the default by 4, the edge of the finest part being
        h / sqrt 2 there (a refined cube corner's step problem was convex only below a third of the
        initial floor, and the run failed there; :attr:`WillmoreFlow.min_tau`).
    iteration_budget : float
        Iteration budget of a step's solve, as a multiple of the median iteration count of the
        last 20 accepted steps (default 2; 0 turns the budget off): a solve still unconverged after
        ``max(iteration_budget_min, iteration_budget * median)`` iterations is cut (status
        ``"Iteration_Budget"``) and the step retried with tau/2 at once, instead of running to
        ``max_iter`` (measured: a 200-iteration attempt that fails costs 4 min on the 2,562-vertex
        ellipsoid, and the same step converges at tau/2 in 5 iterations). Not before the first
        accepted step (``first_step_budget`` then), nor on the last attempt of a step (``max_retries``
        used up). IPOPT and ``newton-krylov`` (Newton iterations, the same rule and status).
    iteration_budget_min : int
        Floor of that budget (default 30).
    first_step_budget : int
        Iteration budget of the attempts of a step when there is no median yet (the first step, and later
        ones until a time step of the main solver is accepted: after Newton steps of a relaxation; default
        100; 0, or ``iteration_budget = 0``: none): an unconverged attempt is cut after this many
        iterations and retried with tau/2, except the last one (``max_retries`` used up). Measured:
        first steps that converge need 3-22 iterations on the registry's surfaces and the study's
        meshes, 57 on the bunny curve, 63 on the 2,562-vertex ellipsoid at tau = h; the noisy capsule
        of the mesh-quality study (578 v) spent 200 iterations in each attempt at tau, tau/2 and
        tau/4 before tau/8 converged in 16 (docs/guide/mesh_quality.md). IPOPT and ``newton-krylov``.
        The ``file`` problem's surfaces use 30: their steps are adaptive, so a cut attempt costs little
        (first steps of tori and genus-2 inputs 2.2-3.5x faster on the same trajectory).
    stall_iterations : int
        Cut a solve (status ``"Stalled"``, then retried with tau/2) whose iterates are stuck: for
        ``stall_iterations`` iterations the objective stayed within 1e-8 (relative), the largest
        constraint violation within a factor 10 and the dual residual max |grad f + J^T lam| within
        a factor 2 of their values at the last iterate that moved; default 15, 0 turns it off. A
        wandering solve is left to the budget (a test on the best values so far cut solves of the
        Fig. 11 bunny that wander for 90 iterations and then converge). IPOPT only.
    relax : bool
        Equilibrium mode, for a minimiser rather than a trajectory: the step size doubles after every step accepted at
        its first attempt (like ``adaptive``) up to ``relax_max_tau``; after a failed doubling it is held for 2, 4, 8,
        ... steps before the next try. :meth:`run` stops early, with ``relaxed`` set, after the first state whose last 3
        steps (``RELAX_WINDOW``) lowered the Willmore energy (:func:`willmore_nlp.geometry.willmore_energy`, scale
        invariant; also with outer constraints alone: they fix the scale; with an anisotropy alone the anisotropic
        Willmore energy, also scale invariant; with ``lam``, ``c0``, a user's term that is not Moebius invariant, or an
        anisotropy and outer constraints, the scheme's energy e, which the flow lowers)
        by less than ``relax_tol`` relative per nominal step (a time step of tau_i < tau counts as tau_i / tau steps, a
        Newton step of ``relax_newton`` as one), or raised it with no Delaunay flip (not counting steps after which the
        mesh was smoothed or remeshed; the light repair, ``remesh_repair``, follows every step and counts; one step is
        too noisy a measure: a Delaunay flip alone moves the energy by ~1e-3 on 642 vertices). Near the equilibrium the
        scheme keeps moving the nodes: tangentially (the Willmore energy then rises by ~1e-3 on a 162-vertex sphere) and
        by an O(tau_tilde) drift that shrinks closed surfaces (dR/dt = -16 tau_tilde / R^5 for a sphere,
        docs/theory/pitfalls.md), which ends in a collapse after long times (t ~ 10-100 for unit surfaces with tau_tilde
        = h^2/100; docs/guide/solver_studies.md). The discrete energy e falls all along it, so it cannot serve as the
        stopping test.
    relax_tol : float
        Relative decrease of the watched energy (the Willmore energy, or e: ``relax``) per nominal step (of size
        tau) below which a relaxation ends (default 1e-4).
    relax_max_tau : float, optional
        Largest step size of a relaxation (default 100 tau).
    relax_check : bool
        When a relaxation of a surface in R^3 (of at most ``STABILITY_MAX_VERTICES`` vertices) ends, test whether
        the state is a minimum: the lowest eigenvalue of the energy's Hessian on normal motions
        (:meth:`~willmore_nlp.flow.WillmoreFlow.stability`, history column ``stability``). At a saddle (an
        eigenvalue below ``-SADDLE_TOL``) the state is moved along the mode (``SADDLE_KICK`` h at most, the sign
        that lowers the energy; history action ``saddle``) and the relaxation goes on, without the test for a rise
        (which ended a c0 = 0.8 vesicle on its saddle), at most ``MAX_SADDLE_KICKS`` times. At a minimum the state
        is polished by Newton steps on normal motions (history action ``polish``, at most ``POLISH_STEPS``) until the
        energy is within ``POLISH_GAP`` (relative) of its quadratic model's minimum there; the message gives that gap
        (column ``stability_gap``). Curves ignore it; above ``STABILITY_MAX_VERTICES`` (50,000), or when the
        iterative eigensolver of larger surfaces does not converge, the message says the state was not tested (and
        why). Default true.
    relax_newton : bool or None
        A relaxation of a surface in R^3 (of at most ``STABILITY_MAX_VERTICES`` vertices) takes Newton steps on
        normal motions of the scheme's energy (:meth:`~willmore_nlp.flow.WillmoreFlow.stability`'s ``newton``, as
        Surface Evolver's ``hessian_seek``) instead of time steps wherever its Hessian there is positive definite:
        each at most ``RELAX_NEWTON_CAP`` h long, halved until the energy falls and the mesh stays above the repair
        thresholds (history solver ``normal-newton``); elsewhere, and when no such step is found, the flow's step.
        The relax test and ``relax_check`` are unchanged, and Newton steps leave the step size as it was. Unset (the
        default since 2026-12-01): on for every relaxation of a surface in R^3, off otherwise; true needs ``relax``
        and a surface in R^3 (refused otherwise); false: time steps only (the vesicle problem's default until the
        evening of 2026-12-01).
    mesh_control : {"auto", "off"}
        Master switch of the mesh-quality control of surfaces ("off": the paper's scheme: no repair
        between steps and ``tangential_control = "auto"`` is "off"; an explicit "meanratio" is kept).
    remesh : {"auto", "off"}
        Surfaces in R^3 only (curves ignore it): mesh repair between steps (:mod:`willmore_nlp.remesh`,
        docs/guide/mesh_quality.md). After every step the light repair (``remesh_repair``); when the
        patch triangles are then still below ``remesh_min_angle`` or above ``remesh_max_edge_ratio``,
        Delaunay flips, (with ``remesh_repair = 0``) tangential smoothing projected onto the surface,
        and isotropic remeshing toward ``remesh_target``, stopping at the first that meets the
        thresholds; then the step NLP is rebuilt for a new
        connectivity and Y[X] solved again. Boundary vertices and the fixed part of a clamped problem
        never move. Changes the state (recorded: ``StepResult.remeshed``, ``stats`` energies before
        and after), so e(X^k) is not guaranteed to decrease across a repair.
    input_repair : bool
        While ``remesh`` is on (surfaces in R^3): an initial mesh whose patch is below ``remesh_min_angle`` or
        above ``remesh_max_edge_ratio`` is repaired before the first step, by Delaunay flips and, when they do not
        suffice, an isotropic remeshing toward the equilateral edge (``remesh_target``) with the new vertices on
        the input's triangles (not lifted onto quadric fits, which a crease would bend; the new triangles chord
        across creases and cone points: 0.38 h on a trimesh cone), taken when it improves the smallest angle (a
        warning says so; default true). That cone (770 v, 4.2 deg) failed its first step at every tau down to
        h/256 as given and flows to a sphere after it (docs/guide/mesh_quality.md). A ``remesh_target`` more than
        10 % away from the input's equilateral edge (:data:`~willmore_nlp.flow.TARGET_CHANGE`) remeshes any input
        toward it (finer or coarser), as the end-of-run resolution warning advises. Not with an explicit clamp
        (``conormal``/``ring`` data).
    steps_from_h : {"none", "tau", "tau_tilde", "both"}
        Which of ``tau`` and ``tau_tilde`` were chosen from the input mesh's mean edge h (tau proportional to h,
        tau_tilde to h^2): when ``input_repair`` changes the mesh they are rescaled to the repaired mesh's h, so
        that they refer to the mesh the flow runs on (default "none": as given). The ``file`` problem sets it for
        the step sizes it chose itself (tau = h, tau_tilde = h^2 / 100): a 128-vertex washer repaired to 1,401
        vertices with ``remesh_target = 0.08`` had run with tau = 4.8 h and tau_tilde = 0.23 h^2 of its own mesh.
    remesh_min_angle : float
        Smallest patch angle (degrees) that triggers the stronger repairs (default 15). The isotropic
        remeshing comes earlier, while the repaired patch's smallest angle is below this plus its fall in
        the step just taken, so that stepped states stay above it where angles fall steadily. An attempt that
        takes it from at or above this to below a third of it is retried at tau / 2 (not a solver's last attempt:
        ``flow.COLLAPSE_FRACTION``, docs/guide/mesh_quality.md, "Thin inputs").
    remesh_max_edge_ratio : float
        Longest/shortest patch edge ratio that triggers it (default 10; a coarse torus grid has 3.6).
    remesh_target : float, optional
        Target edge length of the isotropic remeshing (default: the edge of equilateral triangles with the
        patch's current area and triangle count, :func:`willmore_nlp.remesh.equilateral_edge`, so that a
        remeshing keeps the resolution, e.g. about the vertex count of a closed surface of even triangles: a
        graded one ends with fewer, the 642-vertex oblate vesicle start with 532 after step 1). Given, it also sets the
        resolution of the input (``input_repair``: remeshed toward it before the first step when it differs from
        the input's equilateral edge by more than 10 %).
    remesh_repair : int
        Light repair after every accepted step, while ``remesh`` is on (default 2; 0: only the
        threshold-triggered repair): Delaunay flips, ``remesh_repair`` passes of
        mesh-improving tangential moves placed on a local quadric fit of the surface
        (:func:`willmore_nlp.remesh.tangential_relax`), each move at most as long as the step's move of
        that vertex (``REPAIR_SPEED``: a state the flow does not move is not touched), flips again. The
        vertex count never changes;
        the shape changes by O(h^3) per move (the cubic terms). Keeps the mesh from degrading between the repairs
        (docs/guide/mesh_quality.md). Each pass moves a vertex at most a fifth of its shortest edge: on a genus-2
        flow near rest a vertex that every step slid 0.2 h outran 2 passes until threshold remeshings followed (13 in
        210 steps); 4 ran 300 steps there without one. 4 is the ``torus`` and ``file`` problems' default for closed
        surfaces of genus >= 1 (:data:`~willmore_nlp.flow.REPAIR_PASSES_HANDLES`: the 48x24 torus then stays within
        0.31 % of its grid's Clifford torus to t = 1, 0.68 % with 2); not the flow's (an 800-v noisy torus crept up at
        rest with it, a 72-v torus folded).
    rest_tau_tilde : float
        Closed surfaces with mesh control (not with ``relax``, outer constraints or a boundary): smallest
        tau_tilde at rest, as a fraction of the initial one (default 0.01; 1: off). A closed surface at rest
        is not still under the scheme: its O(tau_tilde) drift shrinks it (a sphere: R^6 = R0^6 -
        96 tau_tilde t, a collapse in finite time; the smoothed box of the mesh-quality study, R = 0.62,
        h^2/100, tau = h: t = 3.77, step 33 failed at every tau). After every ``RELAX_WINDOW`` (3) consecutive
        steps taken at their first attempt with tau >= the nominal tau in which the Willmore energy changed by
        less than ``rest_tol`` relative per unit of the surface's time scale L^4 (L^2 = area / 4 pi), tau_tilde
        is halved (down to this fraction) and Y[X] solved
        again: the drift slows down by the same factor while the flow it approximates is at rest. The history
        columns ``tau_tilde`` and ``rest_steps`` record it (docs/guide/mesh_quality.md).
    rest_tol : float
        Relative change of the Willmore energy per unit time, in the surface's own time scale L^4 (L^2 = area /
        4 pi), below which a step counts as at rest for ``rest_tau_tilde`` (default 3e-5; per step: below
        ``rest_tol tau / L^4``, so that a slow flow at a small tau, e.g. a torus at tau = 1e-3, is not at rest).
        Where the energy is Moebius invariant (isotropic, ``lam = 0``, ``c0 = 0``), a step also counts as at rest
        when its motion is the drift: at least ``flow.DRIFT_SHARE`` (half) of its normal displacement (squared
        lumped L^2 norm) lies in the span of the ten conformal fields, the zero modes of the Willmore energy
        (:func:`willmore_nlp.geometry.conformal_fit`), along which the smooth flow never moves.
    rest_dilation : bool
        Closed surfaces with mesh control and no outer constraint, also in relax mode, with a Moebius-invariant
        energy as above (default True): a step whose motion is the drift has its dilation undone, X
        scaled about the centre by 1 / (1 + c), c the relative dilation of the fit, before Y[X] is solved. The
        smooth flow's motion is L^2-orthogonal to the dilation (the Willmore energy is scale invariant); the
        scheme's O(tau_tilde) drift is almost all dilation (99.9 % on a sphere) and, even with tau_tilde lowered to
        its floor, shrank a refined trimesh box to 45 % of its volume in 30 steps at tau = h. The history column
        ``dilation_undone`` records c, ``drift_share`` the share of every step (docs/guide/mesh_quality.md).
    flip_rest : float
        Near rest, the mesh control keeps the flips that would raise the lumped Willmore energy (default 1e-4): a
        step that changed the lumped W by at most this fraction of it counts as near rest, and while the patch is
        above the repair thresholds the Delaunay flips of a pass are then dropped when they would raise the lumped
        W by more than ``flow.FLIP_RISE`` (1e-4) of it. Near rest the nodes still slide and edges cross the
        Delaunay condition: 8 symmetric flips of edges at 180.5 degrees lifted a 642-v ellipsoid held at its volume
        and area by 0.17 % (its scheme energy by 0.27 %) for two steps. 0: every non-Delaunay edge is flipped, the
        rule before 2026-11-30 (and of run directories written before it) (docs/guide/mesh_quality.md, "Flips near
        rest").
    conformal_gauge : bool
        Closed surfaces in R^3 without constraints (default False): after every step, undo the step's motion
        along the three special conformal fields (:func:`willmore_nlp.geometry.conformal_motion`, applied by
        :func:`willmore_nlp.geometry.special_conformal_map`; the shift is ``stats["conformal_gauge_shift"]``).
        The Willmore energy of a closed surface is Moebius invariant, so the smooth flow has no component
        along these fields and the flow as h -> 0 is unchanged; the discrete flow of a surface of genus >= 1
        whose limit has a nontrivial Moebius orbit (Lawson's genus-2 surface) otherwise drifts along that
        orbit toward images whose curvature the mesh does not resolve
        (docs/guide/mesh_quality_measurements.md, Genus 2).
    """

    solver: str = option("ipopt", Kind("a solver name", lambda v: isinstance(v, str), parse=str))
    first_step_solver: str = option("", Kind("a solver name or '' (solver's)", lambda v: isinstance(v, str),
                                             parse=str))
    fallback_solver: str = option("", Kind("a solver name or '' (none)", lambda v: isinstance(v, str), parse=str))
    large_solver: str = option("", Kind("a solver name or '' (none)", lambda v: isinstance(v, str), parse=str))
    large_vertices: int = option(0, integer(0))
    codegen: bool | None = option(None, BOOL_OR_UNSET)
    max_retries: int = option(4, integer(0))
    check_energy: bool = option(True, BOOL)
    min_angle: float = option(0.5, real(0, 60))
    max_edge_ratio: float = option(1e3, real(1, finite=False))
    max_dihedral: float = option(120.0, real(0, 180, lo_open=True, hi_open=False))
    refine_dihedral: float = option(75.0, real(0, 180, lo_open=True, hi_open=False))
    refine_max_vertices: int = option(50_000, integer(0))
    refine_local: bool = option(True, BOOL)
    energy_rtol: float = option(1e-8, real(0))
    allow_components: bool = option(False, BOOL)
    anisotropy: object = option(None, ANY)
    tangential_weight: float = option(1.0, real(1, MAX_TANGENTIAL_WEIGHT, hi_open=False,
                                                note="1 = the paper's L^2 distance"))
    c0: float = option(0.0, real())
    volume: float | str | None = option(None, TARGET)
    area: float | str | None = option(None, TARGET)
    tangential_control: str = option("auto", one_of(*CONTROL_METHODS))
    tangential_control_weight: float | None = option(None, real(0, lo_open=True, unset="1; 100 on clamped "
                                                                                   "anisotropic surfaces"))
    tangential_control_time: float = option(0.0, real(0))
    redistribute: bool = option(False, BOOL)
    adaptive: bool = option(False, BOOL)
    adaptive_max_wait: int = option(64, integer(0, "0: no limit"))
    convex_start: bool = option(True, BOOL)
    min_tau: float | None = option(None, real(0, unset="0.01 h^4"))
    iteration_budget: float = option(2.0, real(0, note="0: no budget"))
    iteration_budget_min: int = option(30, integer(1))
    first_step_budget: int = option(100, integer(0, "0: no budget"))
    stall_iterations: int = option(15, integer(0, "0: off"))
    relax: bool = option(False, BOOL)
    relax_tol: float = option(1e-4, real(0))
    relax_max_tau: float | None = option(None, real(0, lo_open=True, unset="100 tau"))
    relax_check: bool = option(True, BOOL)
    relax_newton: bool | None = option(None, BOOL_OR_UNSET)
    mesh_control: str = option("auto", one_of("auto", "off"))
    remesh: str = option("auto", one_of("auto", "off"))
    input_repair: bool = option(True, BOOL)
    steps_from_h: str = option("none", one_of("none", "tau", "tau_tilde", "both"))
    remesh_min_angle: float = option(15.0, real(0, 60))
    remesh_max_edge_ratio: float = option(10.0, real(1, finite=False))
    remesh_target: float | None = option(None, real(0, lo_open=True, unset="the initial mean edge"))
    remesh_repair: int = option(2, integer(0))
    rest_tau_tilde: float = option(0.01, real(0, 1, lo_open=True, hi_open=False, note="1: off"))
    rest_tol: float = option(3e-5, real(0))
    rest_dilation: bool = option(True, BOOL)
    flip_rest: float = option(1e-4, real(0))
    conformal_gauge: bool = option(False, BOOL)

    renamed: ClassVar[dict[str, str]] = {"remesh_relax": "remesh_repair"}  # its history action: "relax" then
