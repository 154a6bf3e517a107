"""The benchmark driver (``python -m willmore_nlp.bench``): case selection and the solver table, without running
any step (the subprocess runner is replaced by a fake that returns rows)."""

from pathlib import Path

import numpy as np

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
