"""Shared test helpers (fixtures)."""

import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest


def _check_step_derivatives(ev, z: np.ndarray, p: np.ndarray, rng: np.random.Generator) -> None:
    """Gradient of W, Jacobian of all constraints c = [g; h] and Lagrangian Hessian of a step evaluator
    against central differences (random direction; :func:`willmore_nlp.model.checks.derivative_errors`)."""
    from willmore_nlp.model.checks import derivative_errors

    err = derivative_errors(ev, z, p, rng)
    assert err["gradient"] <= 1e-6 and err["jacobian"] <= 1e-6 and err["hessian"] <= 1e-5, err


@pytest.fixture
def check_step_derivatives() -> Callable[..., None]:
    """:func:`_check_step_derivatives` (assert-style finite-difference check of a StepEvaluator)."""
    return _check_step_derivatives


@pytest.fixture
def octagon_evaluator():
    """(mesh, StepEvaluator) of a regular 8-gon's step problem: the registry's and solvers' option tests."""
    from willmore_nlp.mesh import shapes
    from willmore_nlp.model.build import build_step
    from willmore_nlp.model.evaluator import StepEvaluator

    mesh = shapes.regular_polygon(8)
    setup = build_step(mesh)
    return mesh, StepEvaluator(setup.problem, setup.problem.functions())


def _curves_agree_before_nodes(a: dict, b: dict) -> None:
    """Willmore flow of the ellipse 1 : 0.5 (n = 32, 64, 128; tau = h/8, tau_tilde = h^2/10, to t = 0.04) with
    flow options ``a`` and ``b``: the two curves converge to each other at order > 1.6 in h and faster (by 0.3)
    than their nodes do, while the curves move more than 7 times their distance."""
    from willmore_nlp import WillmoreFlow
    from willmore_nlp.analysis import fit_order, polygon_distance
    from willmore_nlp.mesh import shapes

    hs, curve, nodes = [], [], []
    for n in (32, 64, 128):
        mesh = shapes.ellipse(n, 1.0, 0.5)
        h = mesh.h
        A, B = (WillmoreFlow(mesh, tau=h / 8, tau_tilde=0.1 * h * h, **o) for o in (a, b))
        A.run(t_end=0.04)
        B.run(t_end=0.04)
        hs.append(h)
        curve.append(polygon_distance(A.X, B.X))
        nodes.append(float(np.abs(A.X - B.X).max()))
        assert np.abs(A.X - mesh.vertices).max() > 7 * curve[-1]
    assert fit_order(hs, curve) > 1.6
    assert fit_order(hs, curve) > fit_order(hs, nodes) + 0.3


@pytest.fixture
def curves_agree_before_nodes() -> Callable[[dict, dict], None]:
    """:func:`_curves_agree_before_nodes` (two tangential treatments give the same curve, not the same nodes)."""
    return _curves_agree_before_nodes


def _straight_and_resumed(args: list[str], total: int, first: int, tmp_path: Path) -> tuple:
    """``willmore-nlp run ARGS`` for ``total`` steps into tmp_path/full, and for ``first`` steps into tmp_path/part
    then ``--resume`` to ``total``; returns the two runs (:func:`willmore_nlp.load_run`), whose states a resume test
    compares bit for bit."""
    from willmore_nlp import load_run

    cli = [sys.executable, "-m", "willmore_nlp.cli", "run", *args, "--quiet"]
    full, part = tmp_path / "full", tmp_path / "part"
    for out, steps in ((full, total), (part, first)):
        r = subprocess.run([*cli, "--steps", str(steps), "--out", str(out)], capture_output=True, text=True,
                           timeout=600)
        assert r.returncode == 0, r.stderr
    r = subprocess.run([sys.executable, "-m", "willmore_nlp.cli", "run", "--resume", str(part), "--steps", str(total),
                        "--quiet"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    return load_run(full), load_run(part)


@pytest.fixture
def straight_and_resumed() -> Callable[..., tuple]:
    """:func:`_straight_and_resumed` (a run straight and the same run interrupted and resumed)."""
    return _straight_and_resumed
