"""How fast a signal stops a run, and whether the resumed run equals an uninterrupted one.

Torus 48x24 with tau = 0.02: step 2 needs a 200-iteration IPOPT attempt (rejected) before it
succeeds at tau/2, about 90 s. A signal arrives 1 s into that step (one SIGINT, or two 2 s apart,
or one SIGTERM); the table gives the time from the first signal to the exit, the exit code, the
status, the accepted steps with their retries, and whether ``--resume`` then reproduces the
uninterrupted run bit for bit. Run: ``python reports/reliability/signal_latency.py [OUTDIR]``.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

CLI = [sys.executable, "-m", "willmore_nlp.cli"]
ARGS = ["run", "torus", "--set", "n_major=48", "--set", "n_minor=24", "--set", "tau=0.02", "--steps", "3", "--quiet"]


def states(d: Path) -> dict[str, bytes]:
    out = {}
    for f in sorted((d / "states").glob("state_*.npz")):
        with np.load(f) as z:
            out[f.name] = b"".join(z[k].tobytes() for k in z.files if k != "row")
    return out


def main(base: Path) -> None:
    ref = base / "reference"
    subprocess.run([*CLI, *ARGS, "--out", str(ref)], check=True)
    print("| signals | exit after first signal (s) | exit code | status | accepted steps (retries) "
          "| resume identical |")
    print("|---|---:|---:|---|---|---|")
    for name, sigs in (("SIGINT", [signal.SIGINT]), ("SIGINT x2", [signal.SIGINT, signal.SIGINT]),
                       ("SIGTERM", [signal.SIGTERM])):
        out = base / name.replace(" ", "_")
        p = subprocess.Popen([*CLI, *ARGS, "--out", str(out)], stderr=subprocess.PIPE, text=True)
        while not (out / "states" / "state_000001.npz").exists():
            time.sleep(0.01)
        time.sleep(1.0)
        t0 = time.monotonic()
        p.send_signal(sigs[0])
        while p.poll() is None:
            if len(sigs) > 1 and time.monotonic() - t0 > 2.0:
                p.send_signal(sigs[1])
                sigs = sigs[:1]
            time.sleep(0.01)
        dt = time.monotonic() - t0
        status = json.loads((out / "status.json").read_text())["state"]
        rows = [ln.split(",") for ln in (out / "history.csv").read_text().splitlines()]
        retries = ", ".join(f"{r[0]} ({r[rows[0].index('retries')]})" for r in rows[1:])
        subprocess.run([*CLI, "run", "--resume", str(out), "--quiet"], check=True)
        same = states(out) == states(ref)
        print(f"| {name} | {dt:.1f} | {p.returncode} | {status} | {retries} | {'yes' if same else 'NO'} |")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path(tempfile.mkdtemp()))
