"""The problems/ folder is imported as willmore_nlp._problems: a user's own ``problems`` package in the
working directory neither breaks the CLI nor is shadowed by ours; the installed package list is complete."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

if sys.version_info >= (3, 11):
    import tomllib
else:
    import tomli as tomllib

ROOT = Path(__file__).resolve().parent.parent


def _python(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    return subprocess.run([sys.executable, *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=300)


def test_a_users_problems_package_and_ours_coexist(tmp_path) -> None:
    user = tmp_path / "problems"
    user.mkdir()
    (user / "__init__.py").write_text('MARK = "the user\'s"\n')
    (user / "closed.py").write_text('raise RuntimeError("the user\'s problems/closed.py was imported")\n')
    listed = _python(["-m", "willmore_nlp.cli", "problems"], tmp_path)
    assert listed.returncode == 0, listed.stderr
    assert {"circle", "sphere", "torus", "bunny", "file"} <= {ln.split()[0] for ln in listed.stdout.splitlines()}
    ran = _python(["-m", "willmore_nlp.cli", "run", "circle", "--set", "n=12", "--steps", "1", "--out", "r",
                   "--quiet"], tmp_path)
    assert ran.returncode == 0, ran.stderr
    both = _python(["-c", "from willmore_nlp import registry; registry.load_all(); import problems; "
                          "print(problems.MARK, registry.get('circle').module)"], tmp_path)
    assert both.stdout.split() == ["the", "user's", "willmore_nlp._problems.closed"], both.stderr


def test_installed_packages_are_every_package_of_the_source() -> None:
    """pyproject.toml lists the packages (the mapping of problems/ needs an explicit list): none may be missing."""
    tool = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["tool"]["setuptools"]
    source = {".".join(p.parent.relative_to(ROOT).parts) for p in (ROOT / "willmore_nlp").rglob("__init__.py")}
    data = {k for k in tool["package-data"] if k not in source}  # data folders (no __init__.py), listed as packages
    assert all((ROOT / Path(*k.split("."))).is_dir() for k in data) and "willmore_nlp.mesh.data" in data
    assert set(tool["packages"]) == source | {"willmore_nlp._problems"} | data
    assert tool["package-dir"] == {"willmore_nlp._problems": "problems"}
    assert (ROOT / "problems" / "__init__.py").is_file()


def test_the_core_does_not_import_the_applications(tmp_path) -> None:
    """willmore_nlp/apps (reproduce, study, report, bench) sits on the core: importing the library, its flow,
    solvers, settings and registry (all problems loaded) imports none of it."""
    code = ("import sys, willmore_nlp, willmore_nlp.flow, willmore_nlp.solvers, willmore_nlp.settings, "
            "willmore_nlp.config, willmore_nlp.remesh; from willmore_nlp import registry; registry.load_all(); "
            "print(sorted(m for m in sys.modules if m.startswith('willmore_nlp.apps')))")
    r = _python(["-c", code], tmp_path)
    assert r.returncode == 0 and r.stdout.strip() == "[]", r.stderr


def test_the_version_shown_is_the_packages() -> None:
    """``willmore-nlp --version`` shows ``willmore_nlp.__version__``: the version pyproject.toml installs."""
    import willmore_nlp

    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    assert willmore_nlp.__version__ == project["version"]
