"""Command line, run directories, registry and the public API as a user meets them."""

import csv
import json
import pkgutil
import subprocess
import sys

import numpy as np
import pytest

import willmore_nlp
from willmore_nlp import load_run, registry
from willmore_nlp.cli import default_run_dir

CLI = [sys.executable, "-m", "willmore_nlp.cli"]


def run_cli(*args: str, cwd=None) -> subprocess.CompletedProcess:
    return subprocess.run([*CLI, *args], capture_output=True, text=True, cwd=cwd, timeout=600)


def test_every_problem_module_registers_something() -> None:
    reg = registry.load_all()
    modules = {e.module for e in reg.values()}
    for mod in pkgutil.iter_modules(registry.problems_package().__path__):
        assert f"{registry.PACKAGE}.{mod.name}" in modules, f"problems/{mod.name}.py registers no problem"
    for name in ("circle", "sphere", "hypocycloid", "hypocycloid3d", "torus"):
        assert name in reg
        entry = reg[name]
        assert entry.description
    # the docstring's whole summary, one line: `problems` cut genus2_blending's and torus_hole's two-line summaries
    # after their first line, mid-sentence (a new user's check)
    assert all(e.description.endswith(".") and "\n" not in e.description for e in reg.values())
    assert reg["genus2_blending"].description.endswith("with the rest of the surface fixed.")


@pytest.mark.parametrize("name", ["circle", "sphere", "hypocycloid", "hypocycloid3d", "torus"])
def test_closed_problems_build(name: str) -> None:
    pb, resolved = registry.build(name)
    assert pb.mesh.is_closed
    assert pb.tau > 0 and pb.tau_tilde > 0
    assert set(resolved) == set(registry.get(name).defaults())


def test_large_registry_surfaces_default_to_newton_krylov_with_the_ipopt_fallback() -> None:
    """A built-in surface problem of at least ``LARGE_SURFACE`` vertices (the sphere at subdivisions 5: 10,242) flows
    with newton-krylov and the IPOPT fallback unless a solver is given; the reproduction's sizes (the default sphere,
    642) and curves keep IPOPT; a user's solver replaces both."""
    big, _ = registry.build("sphere", subdivisions=5)
    assert big.mesh.n_vertices >= registry.LARGE_SURFACE > registry.build("sphere")[0].mesh.n_vertices
    options = big.effective_options({})
    assert (options["solver"], options["fallback_solver"]) == ("newton-krylov", "ipopt")
    assert big.effective_options({"solver": "ipopt"}) == {**big.flow_options, "solver": "ipopt"}
    for small in (registry.build("sphere")[0], registry.build("circle", n=20_000)[0]):
        assert "solver" not in small.effective_options({})


def test_public_api_names() -> None:
    for n in ("Mesh", "WillmoreFlow", "StepResult", "willmore_energy", "load_run"):
        assert hasattr(willmore_nlp, n)


def test_cli_problems_lists_registry() -> None:
    r = run_cli("problems")
    assert r.returncode == 0
    for name in ("circle", "sphere", "hypocycloid", "hypocycloid3d", "torus"):
        assert name in r.stdout


def test_cli_version(capsys) -> None:
    """``willmore-nlp --version`` prints the package's version (it was "the following arguments are required:
    command", exit 2)."""
    from willmore_nlp import cli

    with pytest.raises(SystemExit) as exit_:
        cli.main(["--version"])
    assert exit_.value.code == 0
    assert capsys.readouterr().out.strip() == f"willmore-nlp {willmore_nlp.__version__}"


def test_cli_run_circle_writes_run_directory(tmp_path) -> None:
    out = tmp_path / "run"
    r = run_cli("run", "circle", "--out", str(out), "--steps", "3", "--set", "n=32", "--set", "tau=0.01",
                "--quiet")
    assert r.returncode == 0, r.stderr
    with open(out / "history.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [int(x["step"]) for x in rows] == [0, 1, 2, 3]
    for col in ("t", "tau", "objective", "willmore_energy", "measure", "volume", "iterations", "wall_time",
                "q_edge_ratio"):
        assert col in rows[0]
    t = np.array([float(x["t"]) for x in rows])
    np.testing.assert_allclose(t, [0, 0.01, 0.02, 0.03])
    run = load_run(out)
    assert len(run.states) == 4 and run.states[0].n_vertices == 32
    assert run.config["params"]["n"] == 32 and run.config["tau"] == 0.01
    # the circle grew: R(t) = (R0^4 + 2 t)^(1/4)
    R = [np.linalg.norm(s.vertices, axis=1).mean() for s in run.states]
    assert np.all(np.diff(R) > 0)
    np.testing.assert_allclose(R[-1], (2.0**4 + 2 * 0.03) ** 0.25, rtol=1e-3)



def test_cli_run_without_out_writes_a_new_directory_under_runs(tmp_path) -> None:
    """``run TARGET`` without ``--out`` writes runs/NAME, then runs/NAME-2 (never into a directory that holds
    anything), and says where; ``--overwrite`` needs the directory named."""
    (tmp_path / "runs" / "circle-2").mkdir(parents=True)  # a directory the user made: left alone
    (tmp_path / "runs" / "circle-2" / "notes.txt").write_text("mine")
    for expected in ("circle", "circle-3"):
        r = run_cli("run", "circle", "--steps", "1", "--set", "n=16", "--quiet", cwd=tmp_path)
        assert r.returncode == 0, r.stderr
        assert f"writing the run to runs/{expected}" in r.stderr.replace("\\", "/")
        assert (tmp_path / "runs" / expected / "history.csv").is_file()
    assert sorted(p.name for p in (tmp_path / "runs" / "circle-2").iterdir()) == ["notes.txt"]
    r = run_cli("run", "circle", "--steps", "1", "--overwrite", cwd=tmp_path)
    assert r.returncode == 2 and "--overwrite needs --out DIR" in r.stderr
    assert default_run_dir("meshes/dt.obj", tmp_path / "runs").name == "dt"
    assert default_run_dir("my.toml", tmp_path / "runs").name == "my"

def test_cli_run_without_out_names_the_directory_only_for_a_run_it_writes(tmp_path, monkeypatch, capsys) -> None:
    """A run refused when its flow is built (``run vesicle --set volume=1`` without ``--out``) says only its error:
    it had said "writing the run to runs/vesicle" first, and wrote nothing there."""
    from willmore_nlp import cli

    monkeypatch.chdir(tmp_path)
    for bad in ("volume=1", "solver=newton"):
        assert cli.main(["run", "vesicle", "--set", bad, "--steps", "1", "--quiet"]) == 2
        err = capsys.readouterr().err
        assert "writing the run to" not in err and err.strip().count("\n") == 0, err
        assert not (tmp_path / "runs").exists()


def test_cli_run_toml_config_with_mesh_file(tmp_path) -> None:
    from willmore_nlp.mesh import shapes
    from willmore_nlp.mesh.io import save_mesh

    save_mesh(shapes.ellipse(24, 1.5, 1.0), tmp_path / "e.txt")
    (tmp_path / "cfg.toml").write_text('mesh = "e.txt"\nsteps = 2\nlam = 0.5\ntol = 1e-10\n[ipopt]\nmax_iter = 100\n')
    out = tmp_path / "run"
    r = run_cli("run", str(tmp_path / "cfg.toml"), "--out", str(out), "--quiet")
    assert r.returncode == 0, r.stderr
    run = load_run(out)
    assert len(run.states) == 3
    assert run.config["lam"] == 0.5 and run.config["flow_options"]["ipopt.max_iter"] == 100
    e = [row["energy"] for row in run.history]
    assert e[2] < e[1] < e[0]


def test_cli_unknown_key_is_one_line_error(tmp_path) -> None:
    out = tmp_path / "run"
    r = run_cli("run", "circle", "--out", str(out), "--steps", "1", "--set", "nn=3")
    assert r.returncode == 2
    assert r.stderr.strip().count("\n") == 0 and "unknown key 'nn'" in r.stderr
    assert not out.exists()


# -- one user-error class: bad input is one line with exit 2, a bug shows its traceback ---------
def _sliver_sphere() -> "willmore_nlp.Mesh":
    """Icosphere whose triangle 0 is squeezed to a sliver (area about 5e-10)."""
    from willmore_nlp.mesh import shapes

    s = shapes.icosphere(2)
    V = np.array(s.vertices)
    a, b, c = s.simplices[0]
    mid = 0.5 * (V[a] + V[b])
    V[c] = mid + 1e-9 * (V[c] - mid) / np.linalg.norm(V[c] - mid)
    return willmore_nlp.Mesh(V, s.simplices)


@pytest.mark.parametrize("case", ["scaled_1e100", "beyond_1e150", "sliver"])
def test_bad_meshes_are_one_line_errors(tmp_path, case: str, capsys) -> None:
    from willmore_nlp import cli
    from willmore_nlp.mesh import shapes

    e = shapes.ellipse(16, 2.0, 1.0)
    f = tmp_path / "m.npz"
    if case == "scaled_1e100":
        np.savez(f, vertices=e.vertices * 1e100, simplices=e.simplices)
        want = "rescale it"
    elif case == "beyond_1e150":
        np.savez(f, vertices=e.vertices * 1e155, simplices=e.simplices)
        want = "has a coordinate beyond 1e+150"
    else:  # flowed as given: the input repair would flip the sliver away (below)
        m = _sliver_sphere()
        np.savez(f, vertices=m.vertices, simplices=m.simplices)
        want = "triangle 0 (vertices"
    out = tmp_path / "run"
    as_given = ["--set", "input_repair=false"] if case == "sliver" else []
    assert cli.main(["run", str(f), "--out", str(out), "--steps", "1", "--quiet", *as_given]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and want in err and str(f) in err, err
    assert not out.exists()
    if case == "sliver":  # the limits every step must keep are checked after the input repair
        assert cli.main(["run", str(f), "--out", str(out), "--steps", "1", "--quiet"]) == 0
        assert "repaired before the first step by flips" in capsys.readouterr().err


def test_compiler_errors_are_one_line_errors(tmp_path, monkeypatch, capsys) -> None:
    from willmore_nlp import cli

    monkeypatch.setenv("WILLMORE_NLP_CACHE", str(tmp_path / "cache"))
    for var, val in (("WILLMORE_NLP_CFLAGS", "-fbogus-flag"), ("CC", "/bin/false")):
        with monkeypatch.context() as mp:
            mp.setenv(var, val)
            out = tmp_path / var
            assert cli.main(["run", "circle", "--set", "n=12", "--out", str(out), "--steps", "1", "--quiet"]) == 2
            err = capsys.readouterr().err.strip()
            assert err.count("\n") == 0 and "compiling the element kernels failed" in err and "codegen=false" in err
            assert not out.exists()


def test_internal_errors_show_their_traceback_and_io_errors_exit_74(tmp_path, monkeypatch, capsys) -> None:
    import errno

    from willmore_nlp import cli, runner

    # a bug shows its traceback, says that it is one and exits with 70 (EX_SOFTWARE; before 2026-11-30 it exited with
    # 1, like a failed step); an OSError that is not the environment's (ENOENT from the code itself) is a bug too
    for exc in (ValueError("an internal bug"), OSError(errno.ENOENT, "no such thing", "x")):
        def bug(*a: object, exc: Exception = exc, **kw: object) -> int:
            raise exc

        monkeypatch.setattr(runner, "start", bug)
        assert cli.main(["run", "circle", "--out", str(tmp_path / "r"), "--steps", "1"]) == 70
        err = capsys.readouterr().err
        assert "Traceback" in err and str(exc.args[-1]) in err  # not reported as the user's fault
        assert err.strip().splitlines()[-1].startswith("willmore-nlp: internal error (a bug, not a problem with your")
    def too_large(*a: object, **kw: object) -> int:  # (--set n=1e9 under a memory limit)
        raise MemoryError

    monkeypatch.setattr(runner, "start", too_large)
    assert cli.main(["run", "circle", "--out", str(tmp_path / "r"), "--steps", "1"]) == 2
    assert capsys.readouterr().err.strip() == ("willmore-nlp: error: out of memory: the problem is too large for this "
                                               "machine (fewer vertices, or a machine with more memory)")
    monkeypatch.setattr(runner, "start", lambda *a, **kw: int("an internal bug"))
    with pytest.raises(ValueError, match="an internal bug"):  # --debug: the exception itself
        cli.main(["--debug", "run", "circle", "--out", str(tmp_path / "r"), "--steps", "1"])

    def full(*a: object, **kw: object) -> int:
        raise OSError(errno.ENOSPC, "No space left on device", str(tmp_path / "r" / "history.csv"))

    monkeypatch.setattr(runner, "start", full)
    assert cli.main(["run", "circle", "--out", str(tmp_path / "r"), "--steps", "1"]) == 74
    err = capsys.readouterr().err.strip()
    assert err == f"willmore-nlp: error: {tmp_path / 'r' / 'history.csv'}: No space left on device"


def test_every_problem_refuses_bad_parameters_in_one_line() -> None:
    """Every numeric parameter of every registered problem (``file`` aside: its own tests) at 0 and -1, and a word
    where a number belongs, either builds or raises UserInputError (one line, exit 2 on the command line), never
    another exception (found by a new-user check and this sweep: ``genus2_blending h=-1`` hung in the remeshing,
    ``circle_arc n=-1`` raised IndexError, ``surface_blending n_gap=0`` ZeroDivisionError, ``torus_hole hole=0`` a
    NumPy reduction error, ``bunny tangential_weight=zzz`` reached float(); they were reported as the user's error
    with NumPy's words, or as a bug)."""
    import contextlib
    import warnings

    from willmore_nlp.errors import UserInputError

    tried = 0
    for name, entry in sorted(registry.load_all().items()):
        if name == "file":
            continue
        for key, default in entry.defaults().items():
            if isinstance(default, bool) or key == "steps":
                continue
            for value in ([0, -1] if isinstance(default, (int, float)) or default is None else []) + ["zzz"]:
                tried += 1
                with warnings.catch_warnings(), contextlib.suppress(UserInputError):
                    warnings.simplefilter("ignore")
                    registry.build(name, **{key: value})
    assert tried > 100


@pytest.mark.parametrize("command", [["run", "circle", "--steps", "1"], ["export", "RUN", "--out", "x.obj"],
                                     ["report", "RUN"], ["problems"], ["cache", "info"]])
def test_debug_goes_before_or_after_the_command(command: list[str]) -> None:
    """Found by a new-user check: ``willmore-nlp --debug run circle ...`` worked but ``run circle --debug ...`` said
    "unrecognized arguments": every command takes --debug after it too, and without it debug stays off."""
    from willmore_nlp.cli import build_parser

    parser = build_parser()
    assert parser.parse_args([*command, "--debug"]).debug
    assert parser.parse_args(["--debug", *command]).debug
    assert not parser.parse_args(command).debug


def test_resuming_a_relaxed_run_takes_no_step(tmp_path) -> None:
    """A run that relax=true ended before its length (the vesicle discocyte) resumes as a no-op, as a completed run
    of fixed length does: it took a step past its rest and ended with another message (a new user's check)."""
    out = tmp_path / "disco"
    r = run_cli("run", "vesicle", "--set", "reduced_volume=0.65", "--set", "start=oblate", "--steps", "60",
                "--out", str(out), "--quiet")
    assert r.returncode == 0, r.stderr
    status = json.loads((out / "status.json").read_text())
    history = (out / "history.csv").read_text()
    assert status["state"] == "completed" and status["message"].startswith("relaxed") and status["step"] < 60
    r = run_cli("run", "--resume", str(out))
    assert r.returncode == 0 and "nothing to resume" in r.stdout and "past its rest" in r.stdout, r.stderr
    assert (out / "history.csv").read_text() == history
    assert json.loads((out / "status.json").read_text())["message"] == status["message"]
    # a last state without its own row (an older run's): the row is history.csv's, as the resume's rewrite takes it
    last = out / "states" / f"state_{status['step']:06d}.npz"
    with np.load(last) as z:
        kept = {k: z[k] for k in z.files if k != "row"}
    np.savez(last, **kept)
    r = run_cli("run", "--resume", str(out))
    assert r.returncode == 0 and "nothing to resume" in r.stdout and "past its rest" in r.stdout, r.stderr


def test_a_no_op_resume_does_not_repeat_the_inputs_warnings(tmp_path) -> None:
    """Resuming a relaxed run of a poor input (a trimesh capsule, repaired before its first step) printed the input
    repair's warnings before saying there was nothing to resume; a resume that goes on from a later step printed them
    too, as if the input were repaired again (a new user's check, 2026-12-01): they belong to the run's start, and only
    a resume of a run that holds no step yet shows them."""
    import trimesh

    f = tmp_path / "cap.obj"
    trimesh.creation.capsule(height=1.0, radius=0.5, count=[16, 16]).export(f)
    out = tmp_path / "cap"
    r = run_cli("run", str(f), "--set", "relax=true", "--steps", "40", "--out", str(out), "--quiet")
    assert r.returncode == 0 and "repaired before the first step" in r.stderr, r.stderr
    assert json.loads((out / "status.json").read_text())["message"].startswith("relaxed")
    r = run_cli("run", "--resume", str(out))
    assert r.returncode == 0 and "nothing to resume" in r.stdout and "warning" not in r.stderr, r.stderr
    r = run_cli("run", "--resume", str(out), "--steps", "40", "--quiet")
    assert r.returncode == 0 and "repaired before the first step" not in r.stderr, r.stderr


def test_a_problem_of_ones_own_runs_and_resumes_from_python_and_the_cli_says_how(tmp_path) -> None:
    """docs/guide/runs.md's own problem: runner.start / runner.resume write and continue its run directory; the
    command line's --resume, which does not import the user's module, says how to resume it (it said only
    "unknown problem" with the package's list)."""
    (tmp_path / "myproblems.py").write_text(
        "from willmore_nlp import registry\nfrom willmore_nlp.mesh import shapes\n"
        "from willmore_nlp.registry import Problem\n\n\n@registry.register('stretched_ellipsoid')\n"
        "def stretched_ellipsoid(stretch: float = 1.5, subdivisions: int = 2) -> Problem:\n"
        "    '''An icosphere stretched along x3.'''\n    base = shapes.icosphere(subdivisions)\n"
        "    mesh = base.with_vertices(base.vertices * [1.0, 1.0, stretch])\n"
        "    return Problem(mesh, tau=mesh.h, tau_tilde=mesh.h**2 / 100, steps=20)\n")
    go = ("import myproblems\nfrom willmore_nlp import registry, runner\nfrom willmore_nlp.config import RunSpec\n"
          "pb, params = registry.build('stretched_ellipsoid', stretch=1.8)\n"
          "print(runner.start(RunSpec('stretched_ellipsoid', pb, params, steps=2), 'runs/mine', quiet=True))\n"
          "print(runner.resume('runs/mine', steps=3, quiet=True))\n")
    r = subprocess.run([sys.executable, "-c", go], capture_output=True, text=True, cwd=tmp_path, timeout=600)
    assert r.returncode == 0 and r.stdout.split() == ["0", "0"], r.stderr
    assert len(load_run(tmp_path / "runs" / "mine").states) == 4  # states 0-3
    r = run_cli("run", "--resume", "runs/mine", "--steps", "4", cwd=tmp_path)
    assert r.returncode == 2
    assert "problem 'stretched_ellipsoid' is not registered here" in r.stderr
    assert "willmore_nlp.runner.resume(RUN)" in r.stderr


def test_the_progress_bar_is_redrawn_while_a_step_runs(monkeypatch) -> None:
    """A new user's check: an 8,192-vertex torus showed "0/8 [00:00<?" for the 340 s of its first step (tqdm redraws
    only on an update). The bar now has a daemon thread that redraws it every HEARTBEAT_SECONDS (so its elapsed time
    runs) and stops with it; a quiet run has none. A retry's reason in the bar is cut at a word, with "..."."""
    import time

    from willmore_nlp import runner
    from willmore_nlp.flow import _shortened

    monkeypatch.setattr(runner, "HEARTBEAT_SECONDS", 0.01)
    bar = runner._Bar(10, "step", quiet=False)
    drawn: list[float] = []
    bar.bar.refresh = lambda *args, **kw: drawn.append(time.monotonic())
    deadline = time.monotonic() + 30
    while len(drawn) < 3 and time.monotonic() < deadline:
        time.sleep(0.01)
    bar.close()
    assert len(drawn) >= 3 and bar._beat is not None and not bar._beat.is_alive()
    assert runner._Bar(10, "step", quiet=True)._beat is None
    text = "tau=0.0896: newton-krylov: solver did not converge (maximum iterations, 63 iterations) " * 3
    short = _shortened(text)
    assert len(short) <= 160 and short.endswith("...") and text.startswith(short[:-3]) and text[len(short) - 3] == " "
    assert _shortened("short reason") == "short reason"
