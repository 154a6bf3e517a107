"""Tutorial: a solver study, several solvers x step sizes on one problem, run on Dask.

The same as ``willmore-nlp compare circle --solvers ipopt,newton,semi-implicit --taus h,4h --set n=64
--steps 5 --out tutorial_study``. Every solver solves the same step problem (semi-implicit is the linear
baseline); the summary lists each case's iterations, time and the largest stable step.
Run with ``python docs/tutorials/solver_study.py``.
"""

import json
from pathlib import Path

from willmore_nlp.apps.study import make_grid, run_study


def main(n: int = 64, steps: int = 5, out: str = "tutorial_study", workers: int = 2) -> dict[str, dict]:
    cases = make_grid("circle", ["ipopt", "newton", "semi-implicit"], ["h", "4h"], params={"n": n}, steps=steps)
    summary = run_study(cases, out, n_workers=workers, progress=False)
    print(summary.read_text())
    records = {}
    for f in sorted((Path(out) / "cases").glob("*.json")):
        rec = json.loads(f.read_text())
        records[f"{rec['case']['solver']} tau={rec['case']['tau']}"] = rec
    return records


if __name__ == "__main__":
    main()
