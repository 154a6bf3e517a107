"""The benchmark driver (``python -m willmore_nlp.bench``): case selection and the solver table, without running
any step (the subprocess runner is replaced by a fake that returns rows)."""

from pathlib import Path

import numpy as np
import pytest

from willmore_nlp.apps import bench


def _fake_subprocess(calls: list[tuple[str, str]]):
    """A stand-in for :func:`bench._subprocess`: step times c N^1.1 (IPOPT: 10 times slower), X^1 saved."""

    def run(case: str, codegen: bool, timeout: float, solver: str = "ipopt", save: str | None = None) -> dict:
        calls.append((case, solver))
        n = bench._mesh(case).n_vertices
        t = 1e-4 * n**1.1 * (10.0 if solver == "ipopt" else 1.0)
        if save:
            np.save(save, np.full((n, 3), 1.0 if solver == "ipopt" else 1.0 + 1e-9))
        return {"case": case, "N": n, "codegen": codegen, "solver": solver, "h": 0.1, "step_s": t,
                "step2_s": t / 2, "iterations2": 4, "step3_s": t / 3, "iterations3": 3, "peak_rss_gb": 0.1,
                "load": "1.0", "load_end": "2.0"}

    return run


def test_ipopt_max_runs_larger_cases_with_the_other_solvers_alone(monkeypatch, tmp_path: Path) -> None:
    """Cases above --ipopt-max run newton-krylov only (no speed-up, no dX), the others both; the table gives the
    speed-up (10 by construction), dX / h (1e-9 / 0.1) and the fitted exponent of the fake times (1.10)."""
    calls: list[tuple[str, str]] = []
    monkeypatch.setattr(bench, "_subprocess", _fake_subprocess(calls))
    out = tmp_path / "b"
    assert bench.main(["--spheres", "1", "2", "3", "--torus", "--vm-max", "0", "--ipopt-max", "200",
                       "--out", str(out)]) == 0
    assert calls == [("sphere:1", "ipopt"), ("sphere:1", "newton-krylov"), ("sphere:2", "ipopt"),
                     ("sphere:2", "newton-krylov"), ("sphere:3", "newton-krylov")]
    text = out.with_suffix(".md").read_text()

    def cells(line: str) -> list[str]:
        return [c.strip() for c in line.strip().strip("|").split("|")]

    rows = {cells(line)[0]: cells(line) for line in text.splitlines()
            if line.startswith("| sphere") and "newton-krylov" in line}
    assert set(rows) == {"sphere:1", "sphere:2", "sphere:3"}
    head = cells(next(line for line in text.splitlines() if line.startswith("| case | N | solver")))
    col = {name: head.index(name) for name in ("speed-up", "speed-up 3", "max abs dX / h", "IPOPT load", "load")}
    assert float(rows["sphere:2"][col["speed-up"]]) == float(rows["sphere:2"][col["speed-up 3"]]) == 10.0
    assert abs(float(rows["sphere:2"][col["max abs dX / h"]]) - 1e-8) < 1e-12
    assert rows["sphere:2"][col["IPOPT load"]] == "1.0-2.0"
    assert rows["sphere:3"][col["speed-up"]] == "" and rows["sphere:3"][col["load"]] == "1.0-2.0"
    assert ("Fitted exponent of newton-krylov's step time vs N (spheres): step 1 **1.10**, step 2 **1.10**, "
            "step 3 **1.10**") in text


def test_control_steps_report_the_mesh_controls_share_of_a_step() -> None:
    """Two steps of the 162-vertex sphere with the surface defaults: the light repair runs after each, its time is
    part of the step's, and the table row carries the case and its share."""
    row = bench.run_control_case("sphere:2", 2)
    assert (row["N"], row["steps"], row["actions"]) == (162, 2, "repair")
    assert 0 < row["control_s"] < row["step_s"] and 0 < row["control_share"] < 1
    lines = bench.control_table([row, {"case": "torus:8x4", "solver": "ipopt", "error": ["boom"]}])
    assert lines[-2].startswith("| sphere:2 | 162 | ipopt | 2 |") and "repair" in lines[-2]
    assert lines[-1] == "| torus:8x4 | | ipopt | failed: ['boom'] |"


def test_the_header_names_the_blas_threads_openblas_reads(monkeypatch) -> None:
    """OpenBLAS takes OMP_NUM_THREADS when OPENBLAS_NUM_THREADS is unset: the header said "unset (one per core)" for
    a benchmark run with OMP_NUM_THREADS=1 (found by a new-user check)."""
    from willmore_nlp.apps.bench import _blas_threads

    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    assert _blas_threads() == "1 (OMP_NUM_THREADS)"
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "2")
    assert _blas_threads() == "2 (OPENBLAS_NUM_THREADS)"
    monkeypatch.delenv("OPENBLAS_NUM_THREADS")
    monkeypatch.delenv("OMP_NUM_THREADS")
    assert _blas_threads() == "unset (one per core)"


def test_a_case_that_times_out_becomes_a_row_and_the_benchmark_goes_on(monkeypatch, tmp_path: Path) -> None:
    """``--timeout 2`` on the 162-vertex sphere ended in a traceback (subprocess.TimeoutExpired), exit 1, and no .md or
    .csv: the rows measured were lost (found by a new-user check). A case stopped at its timeout is a row saying so;
    the rows before it and the cases after it are kept (here a fake row, then a real subprocess given 0.01 s)."""
    calls: list[tuple[str, str]] = []
    fake, real = _fake_subprocess(calls), bench._subprocess

    def run(case: str, codegen: bool, timeout: float, solver: str = "ipopt", save: str | None = None) -> dict:
        return fake(case, codegen, timeout, solver, save) if case == "sphere:1" else real(case, codegen, 0.01, solver)

    monkeypatch.setattr(bench, "_subprocess", run)
    out = tmp_path / "b"
    assert bench.main(["--spheres", "1", "2", "--torus", "8x4", "--vm-max", "0", "--solvers", "ipopt",
                       "--out", str(out)]) == 0
    lines = out.with_suffix(".md").read_text().splitlines()
    assert any(line.startswith("| sphere:1 | 42 | True |") for line in lines)
    for case in ("sphere:2", "torus:8x4"):
        assert f"| {case} | | True | failed: ['timed out after 0.01 s (--timeout), stopped'] |" in lines
    assert len(out.with_suffix(".csv").read_text().splitlines()) == 1 + 3


def test_help_says_the_default_torus_runs_and_how_to_skip_it(capsys) -> None:
    """``--spheres 2`` alone also ran the 4,608-vertex default torus, which --help did not say (new-user check)."""
    with pytest.raises(SystemExit):
        bench.main(["--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "default 96x48, 4,608 vertices, also when only --spheres is given" in text
    assert "none: --torus with no grid" in text
