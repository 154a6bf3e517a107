"""Typed settings: one rule per option, the same message from every entry point; IPOPT's options checked
statically against IPOPT's own documentation and agreeing with IPOPT's own checks."""

from __future__ import annotations

import dataclasses
import html
import inspect
import json
import re
import subprocess
import sys

import casadi as ca
import pytest

from willmore_nlp import cli
from willmore_nlp.config import ConfigError, resolve
from willmore_nlp.errors import UserInputError
from willmore_nlp.flow import WillmoreFlow
from willmore_nlp.mesh import shapes
from willmore_nlp.settings import FlowSettings
from willmore_nlp.solvers import solver_names, solver_settings
from willmore_nlp.solvers.ipopt import OPTIONS_FILE, check_ipopt_option


def ipopt_doc_table(text: str) -> dict[str, list]:
    """IPOPT's ``print_options_mode=doxygen`` documentation -> the entries of ``ipopt_options.json``.

    Regenerate the file after an IPOPT upgrade with ``dump(ipopt_doc_table(installed_ipopt_doc()))``.
    """
    out: dict[str, list] = {}
    for name, body in re.findall(r"\\anchor OPT_(\w+)\n(.*?)</blockquote>", text, re.S):
        body = html.unescape(re.sub(r"<sup>([^<]*)</sup>", r"e\1", body))
        typ = re.search(r"this (real|integer|string) option", body).group(1)
        if typ == "string":
            short = re.search(r"Possible values: (.+)$", body, re.M)
            choices = ([c.strip() for c in short.group(1).split(",")] if short
                       else re.findall(r"^ - ([^:]+):", body, re.M))
            out[name] = ["string", None if "*" in choices or not choices else choices]
            continue
        rng = re.search(r"valid range for this \w+ option is (.*?) and its default", body, re.S).group(1)
        lo, lo_open, hi, hi_open = None, False, None, False
        if rng != "unrestricted":
            parts = re.split(r"\s*(<|≤)\s*", rng.strip())
            i = parts.index(name)
            if i == 2:
                lo, lo_open = float(parts[0]), parts[1] == "<"
            if len(parts) > i + 1:
                hi, hi_open = float(parts[i + 2]), parts[i + 1] == "<"
        out[name] = [typ, lo, lo_open, hi, hi_open]
    return out


def dump(table: dict[str, list]) -> str:
    """The file format of ``ipopt_options.json``: one option per line."""
    return "{\n" + ",\n".join(f"  {json.dumps(k)}: {json.dumps(v)}" for k, v in sorted(table.items())) + "\n}\n"


def installed_ipopt_doc() -> str:
    """The option documentation printed by the IPOPT that CasADi loads (a subprocess: it writes to C stdout)."""
    code = ("import casadi as ca; x = ca.MX.sym('x'); ca.nlpsol('d', 'ipopt', {'x': x, 'f': x**2},"
            " {'print_time': False, 'ipopt': {'print_options_documentation': 'yes', 'print_advanced_options': 'yes',"
            " 'print_options_mode': 'doxygen', 'sb': 'yes'}})(x0=1)")
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout


def test_ipopt_table_is_the_installed_ipopts_documentation() -> None:
    table = ipopt_doc_table(installed_ipopt_doc())
    assert len(table) > 250 and table["tol"] == ["real", 0.0, True, None, False]
    assert OPTIONS_FILE.read_text(encoding="utf-8") == dump(table)


def _ipopt_accepts(name: str, value: object) -> bool:
    """IPOPT's own verdict: does building a solver with the option succeed?"""
    x = ca.MX.sym("x")
    try:
        ca.nlpsol("probe", "ipopt", {"x": x, "f": x**2}, {"print_time": False,
                                                          "ipopt": {name: value, "print_level": 0, "sb": "yes"}})
    except RuntimeError:
        return False
    return True


@pytest.mark.parametrize(("name", "value"), [
    ("tol", 1e-7), ("tol", 0.0), ("tol", -1.0), ("max_iter", 5), ("max_iter", -1), ("print_level", 12),
    ("acceptable_tol", 0.0), ("mu_strategy", "adaptive"), ("mu_strategy", "bogus"), ("mumps_pivot_order", 7),
    ("mumps_pivot_order", 8), ("bound_frac", 0.5), ("bound_frac", 0.6), ("hessian_constant", "yes"),
    ("hessian_constant", "maybe"), ("no_such_option", 1), ("acceptable_iter", 0), ("alpha_red_factor", 1.0)])
def test_static_ipopt_check_agrees_with_ipopt(name: str, value: object) -> None:
    try:
        check_ipopt_option(name, value)
        ours = True
    except UserInputError:
        ours = False
    assert ours == _ipopt_accepts(name, value)


def test_every_option_is_documented() -> None:
    """docs/reference/options.md takes each option's meaning from its class docstring: none may lack one."""
    classes = [FlowSettings, *(solver_settings(n) for n in solver_names())]
    for cls in classes:
        doc = inspect.getdoc(cls) or ""
        for f in dataclasses.fields(cls):
            assert re.search(rf"^{f.name} : ", doc, re.M), (cls.__name__, f.name)


def _last_line(capsys: pytest.CaptureFixture[str], argv: list[str]) -> str:
    assert cli.main(argv) == 2
    return capsys.readouterr().err.strip()


@pytest.mark.parametrize(("key", "value", "text"), [
    ("max_retries", -1, "max_retries must be an integer >= 0, got -1"),
    ("stall_iterations", 2.5, "stall_iterations must be an integer >= 0 (0: off), got 2.5"),
    ("remesh", "sometimes", "remesh must be 'auto' or 'off', got 'sometimes'"),
    ("min_tau", -1, "min_tau must be a number >= 0 or unset (0.01 h^4), got -1")])
def test_one_rule_from_every_entry_point(tmp_path, capsys, key: str, value: object, text: str) -> None:
    """The Python API, a TOML config, ``--set`` and ``compare --option`` refuse a bad value with one message."""
    mesh = shapes.regular_polygon(12)
    with pytest.raises(UserInputError) as api:
        WillmoreFlow(mesh, mesh.h, 0.1 * mesh.h**2, **{key: value})
    assert str(api.value) == text
    toml = tmp_path / "c.toml"
    toml.write_text(f'problem = "circle"\n{key} = {json.dumps(value)}\n')
    assert _last_line(capsys, ["run", str(toml), "--out", str(tmp_path / "r"), "--steps", "1"]).endswith(
        f"c.toml: {text}")
    assert _last_line(capsys, ["run", "circle", "--set", f"{key}={value}", "--out", str(tmp_path / "r"),
                               "--steps", "1"]) == f"willmore-nlp: error: --set: {text}"
    assert _last_line(capsys, ["compare", "circle", "--option", f"{key}={value}", "--out", str(tmp_path / "s"),
                               "--quiet"]) == f"willmore-nlp: error: --option {key}: {text}"
    assert not (tmp_path / "r").exists() and not (tmp_path / "s").exists()


def test_solver_options_are_the_solvers_own() -> None:
    """``armijo`` and ``cholesky`` are settable from a config, checked by the chosen solver only."""
    spec = resolve("circle", {"solver": "newton-krylov", "cholesky": "scipy", "armijo": "1e-3"})
    assert spec.flow_options == {"solver": "newton-krylov", "cholesky": "scipy", "armijo": 1e-3}
    with pytest.raises(ConfigError, match="--set: cholesky is an option of solver newton-krylov, not of sqp"):
        resolve("circle", {"solver": "sqp", "cholesky": "scipy"})
    with pytest.raises(UserInputError, match="solver sqp: unknown option\\(s\\) cholesky_x; known: tol, max_iter"):
        solver_settings("sqp").from_options({"cholesky_x": 1})
    with pytest.raises(ConfigError, match="solver newton-krylov: option cg_rebuild must be an integer >= 1, got 0"):
        resolve("circle", {"solver": "newton-krylov", "cg_rebuild": "0"})
    with pytest.raises(ConfigError, match="IPOPT option mu_strategy = 'x': not a valid setting"):
        resolve("circle", {"ipopt.mu_strategy": "x"})
    assert FlowSettings(relax=True).relax and FlowSettings().defaults()["remesh_repair"] == 2


def test_kinds_say_what_they_allow() -> None:
    """The words of the messages come from the rule itself (docs/reference/options.md shows them too)."""
    from willmore_nlp.settings import integer, one_of, real

    assert real().what == "a finite number" and real().ok(-1e300) and not real().ok(float("inf"))
    assert real(finite=False).what == "a number" and real(finite=False).ok(float("inf"))
    assert real(0, 60).what == "a number in [0, 60)" and not real(0, 60).ok(60) and real(0, 60).ok(0)
    assert real(1, finite=False).ok(float("inf")) and not real(1).ok(True)
    assert real(0, lo_open=True, unset="auto").what == "a number > 0 or unset (auto)" and real(0, unset="a").ok(None)
    assert integer(1).ok(2.0) and integer(1).convert(2.0) == 2 and not integer(1).ok(1.5) and not integer(0).ok(False)
    assert one_of("a", "b", "c").what == "one of 'a', 'b', 'c'" and one_of("a", "b").what == "'a' or 'b'"


def test_the_light_repairs_old_name_is_still_read(tmp_path) -> None:
    """``remesh_relax`` (before it became ``remesh_repair``, beside the equilibrium mode ``relax``) still works:
    in the API, in a config and so in the config.json of an older run directory that is resumed."""
    mesh = shapes.torus(1.0, 0.5, 12, 6)
    assert WillmoreFlow(mesh, 1e-3, 0.01 * mesh.h**2, remesh_relax=0).settings.remesh_repair == 0
    assert resolve("torus", {"remesh_relax": "3"}).flow_options == {"remesh_repair": 3}
    with pytest.raises(UserInputError, match="remesh_repair must be an integer >= 0, got -1"):
        FlowSettings(**FlowSettings.split({"remesh_relax": -1})[0])


def test_problem_parameters_read_like_options() -> None:
    """A problem parameter defaulting to None is read like an option: bunny's ``redistribute=false`` is False
    (it used to stay the string 'false', which the factory took for True)."""
    from willmore_nlp import registry

    assert registry.check_params("bunny", {"redistribute": "false", "n": "64", "h": "0.1"}) == {
        "redistribute": False, "n": 64, "h": 0.1}
    pb, _ = registry.build("bunny", redistribute="false", gamma="gamma2:0.1", n="64")
    assert pb.flow_options["redistribute"] is False
    with pytest.raises(UserInputError, match=r"n must be an integer, got '6\.5'"):
        registry.check_params("bunny", {"n": "6.5"})


def test_api_misuse_is_one_clear_error_and_numpy_scalars_are_numbers() -> None:
    """Found by trying the API as a new user (2026-11-30): ``run(t_end=nan)`` stepped forever (t_end - t is nan, which
    no stopping test meets), ``run(t_end=-1)`` / ``run(steps=-1)`` returned nothing silently and ``steps=2.5`` ran 3
    steps, an array in place of a Mesh failed five frames deep with an AttributeError, complex vertices lost their
    imaginary parts with only numpy's warning, and ``tau=np.float32(0.01)`` was refused as not a number."""
    import numpy as np

    from willmore_nlp.mesh import Mesh, MeshError

    polygon = shapes.regular_polygon(16)
    flow = WillmoreFlow(polygon, np.float32(0.01), np.float64(1e-3))
    assert flow.tau == pytest.approx(0.01)
    for kwargs, text in [({"t_end": float("nan")}, "t_end must be a finite time >= 0, got nan"),
                         ({"t_end": float("inf")}, "t_end must be"), ({"t_end": -1.0}, "t_end must be"),
                         ({"steps": -1}, "steps must be an integer >= 0, got -1"), ({"steps": 2.5}, "got 2.5"),
                         ({}, "run needs t_end or steps")]:
        with pytest.raises(UserInputError, match=re.escape(text)):
            flow.run(**kwargs)
    assert flow.k == 0
    assert len(flow.run(steps=np.int64(2))) == 2 and len(flow.run(steps=0)) == 0
    assert len(flow.run(t_end=np.float32(0.03))) == 1 and flow.t == pytest.approx(0.03)
    with pytest.raises(UserInputError, match=r"mesh must be a willmore_nlp\.mesh\.Mesh .*got ndarray"):
        WillmoreFlow(np.zeros((16, 2)), 0.01, 1e-3)
    with pytest.raises(MeshError, match="vertices are complex numbers"):
        Mesh(polygon.vertices + 5j * polygon.vertices, polygon.simplices)
    with pytest.raises(UserInputError, match="tau must be a number > 0"):
        WillmoreFlow(polygon, np.bool_(True), 1e-3)


def test_a_misspelt_flow_option_is_named_as_such() -> None:
    """WillmoreFlow passes the options it does not know to the solver; a misspelt flow option reached IPOPT's check and
    was called an unknown IPOPT option: now the message says it is neither and names the closest option."""
    m = shapes.regular_polygon(20)
    with pytest.raises(UserInputError, match="unknown option tangential_wieght = 3: neither a flow option nor an "
                                             "IPOPT option; did you mean 'tangential_weight'"):
        WillmoreFlow(m, 0.1, 0.01, tangential_wieght=3)
    with pytest.raises(UserInputError, match="did you mean 'max_iter'"):
        WillmoreFlow(m, 0.1, 0.01, max_itr=3)


def test_an_option_of_another_solver_names_that_solver(tmp_path, capsys) -> None:
    """Found by a new-user check: ``--set cholesky=scipy`` (the default solver ipopt) said "neither a flow option nor an
    IPOPT option" and ``--set cg_max_iter=5`` "did you mean 'max_iter'?", though both are newton-krylov's options:
    every solver's check now names the solver(s) whose option it is, on the command line and in the API."""
    out = ["--steps", "1", "--out", str(tmp_path / "r")]
    assert _last_line(capsys, ["run", "circle", "--set", "cholesky=scipy", *out]) == (
        "willmore-nlp: error: --set: cholesky is an option of solver newton-krylov, not of ipopt: add --set "
        "solver=newton-krylov (solver='newton-krylov' in Python)")
    assert "cg_max_iter is an option of solver newton-krylov, not of ipopt" in _last_line(
        capsys, ["run", "circle", "--set", "cg_max_iter=5", *out])
    assert "armijo is an option of solvers gd, lbfgs, newton, newton-krylov, not of ipopt: add --set solver=NAME " \
           "with one of them" in _last_line(capsys, ["run", "circle", "--set", "armijo=1e-3", *out])
    assert "ipopt.mu_strategy: IPOPT is not used (solver sqp, fallback_solver none): add --set " \
           "fallback_solver=ipopt or solver=ipopt" in _last_line(
        capsys, ["run", "circle", "--set", "solver=sqp", "--set", "ipopt.mu_strategy=adaptive", *out])
    assert "--option: cholesky is an option of solver newton-krylov, not of lbfgs" in _last_line(
        capsys, ["compare", "circle", "--solvers", "lbfgs", "--option", "cholesky=scipy", "--out", str(tmp_path / "s"),
                 "--quiet"])
    m = shapes.regular_polygon(12)
    with pytest.raises(UserInputError, match="cholesky is an option of solver newton-krylov, not of ipopt"):
        WillmoreFlow(m, 0.1, 1e-3, cholesky="scipy")
    with pytest.raises(UserInputError, match="warm_start_init_point is an option of solver ipopt, not of gd"):
        WillmoreFlow(m, 0.1, 1e-3, solver="gd", warm_start_init_point="yes")
    assert not (tmp_path / "r").exists() and not (tmp_path / "s").exists()


def test_ipopt_options_are_ipopts_whichever_solver_it_is(tmp_path) -> None:
    """``ipopt.NAME`` keys, a config's ``[ipopt]`` table and ``ipopt={...}`` counted as ``NAME`` of whichever solver was
    ``solver`` (a new-user check): a surface file of >= 500 vertices (newton-krylov with the IPOPT fallback) refused
    ``[ipopt] mu_strategy = "adaptive"`` ("an option of solver ipopt, not of newton-krylov"), and
    ``solver='newton-krylov', ipopt={'max_iter': 1}`` cut newton-krylov to one iteration. Now they are IPOPT's, as
    ``solver``, ``first_step_solver``, ``fallback_solver`` or ``large_solver``, beside the other solver's own options of
    the same name, and refused in one line when the flow does not use IPOPT."""
    from willmore_nlp.mesh.io import save_mesh
    from willmore_nlp.settings import route_solver_options

    save_mesh(shapes.icosphere(3), tmp_path / "ico.obj")
    (tmp_path / "cfg.toml").write_text('mesh = "ico.obj"\nsteps = 1\nmax_iter = 20\n[ipopt]\nmu_strategy = "adaptive"\n'
                                       'max_iter = 100\n')
    spec = resolve(str(tmp_path / "cfg.toml"))
    options = spec.problem.effective_options(spec.flow_options)
    assert (options["solver"], options["fallback_solver"]) == ("newton-krylov", "ipopt")
    assert route_solver_options(spec.flow_options, options) == {
        "newton-krylov": {"max_iter": 20}, "ipopt": {"ipopt.mu_strategy": "adaptive", "ipopt.max_iter": 100}}
    m = shapes.icosphere(1)
    flow = WillmoreFlow(m, 0.1, 1e-3, solver="newton-krylov", fallback_solver="ipopt", max_iter=5,
                        ipopt={"max_iter": 1, "mu_strategy": "adaptive"})
    assert flow.solver.name == "newton-krylov" and flow.solver.max_iter == 5
    flow._make_solver("ipopt")
    assert flow.solver.options["max_iter"] == 1 and flow.solver.options["mu_strategy"] == "adaptive"
    for role in ("first_step_solver", "large_solver"):
        flow = WillmoreFlow(m, 0.1, 1e-3, solver="newton-krylov", max_iter=5, **{role: "ipopt", "ipopt.max_iter": 7})
        assert flow._solver_options("ipopt") == {"ipopt.max_iter": 7}
        assert flow._solver_options("newton-krylov") == {"max_iter": 5}
    with pytest.raises(UserInputError, match=re.escape(
            "ipopt.max_iter: IPOPT is not used (solver newton-krylov, fallback_solver none): add --set "
            "fallback_solver=ipopt or solver=ipopt (fallback_solver='ipopt' in Python), or leave ipopt.max_iter out")):
        WillmoreFlow(m, 0.1, 1e-3, solver="newton-krylov", ipopt={"max_iter": 1})
    assert cli.main(["run", str(tmp_path / "cfg.toml"), "--set", "solver=sqp", "--out", str(tmp_path / "r")]) == 2
    assert not (tmp_path / "r").exists()
    # a run directory written before, with IPOPT unused, resumes with the options it ran with
    from willmore_nlp.runner import spec_from_config

    old = {"solver": "newton-krylov", "ipopt.max_iter": 3}
    cfg = {"problem": "circle", "params": {"n": 12}, "flow_options": old, "effective_flow_options": old}
    assert spec_from_config(cfg, "config.json").flow_options == {"solver": "newton-krylov", "max_iter": 3}
    both = {**old, "fallback_solver": "ipopt"}
    assert spec_from_config({**cfg, "flow_options": both, "effective_flow_options": both},
                            "config.json").flow_options == both


def test_ipopt_options_as_one_mapping() -> None:
    """Found by a new-user check: a TOML config takes an ``[ipopt]`` table, so users try
    ``WillmoreFlow(m, ..., ipopt={"max_iter": 10})``, which raised a raw ``TypeError: IpoptSettings() got multiple
    values for keyword argument 'ipopt'``: the mapping's entries are now IPOPT options, checked like the flat ones."""
    m = shapes.regular_polygon(12)
    flow = WillmoreFlow(m, 0.1, 1e-3, ipopt={"max_iter": 10, "mu_strategy": "adaptive"})
    assert flow.solver.options["max_iter"] == 10 and flow.solver.options["mu_strategy"] == "adaptive"
    for kwargs, text in [({"ipopt": {"max_iter": 10}, "max_iter": 5},
                          "option max_iter of solver ipopt is given twice, as max_iter and as ipopt.max_iter"),
                         ({"ipopt": {"max_iter": 10}, "ipopt.max_iter": 5}, "and as ipopt.max_iter"),
                         ({"ipopt": {"mu_strategy": "x"}}, "IPOPT option mu_strategy = 'x': not a valid setting"),
                         ({"ipopt": 3}, "ipopt must be a mapping of IPOPT options (name: value), got 3")]:
        with pytest.raises(UserInputError, match=re.escape(text)):
            WillmoreFlow(m, 0.1, 1e-3, **kwargs)
