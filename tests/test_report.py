"""Run reports: every artefact exists, images decode, Markdown links resolve."""

import re
import subprocess
import sys

import matplotlib.image as mpimg
import numpy as np
import pytest

from willmore_nlp.report import markdown_to_html, snapshot_indices


@pytest.mark.parametrize(("problem", "sets"), [("circle", ["n=16"]), ("sphere", ["subdivisions=1"]),
                                               ("hypocycloid3d", ["n=60"])])
def test_report_artefacts(tmp_path, problem: str, sets: list[str]) -> None:
    run = tmp_path / "run"
    args = [sys.executable, "-m", "willmore_nlp.cli", "run", problem, "--out", str(run), "--steps", "3", "--quiet"]
    for s in sets:
        args += ["--set", s]
    subprocess.run(args, check=True, capture_output=True)
    r = subprocess.run([sys.executable, "-m", "willmore_nlp.cli", "report", str(run)], capture_output=True,
                       text=True, check=True)
    rep = run / "report"
    assert "report.md" in r.stdout
    md = (rep / "report.md").read_text()
    links = re.findall(r"\]\(([^)]+)\)", md)
    assert len(links) == 5
    for link in links:
        img = mpimg.imread(rep / link)
        assert img.ndim == 3 and img.shape[0] > 100 and img.shape[1] > 100
        assert np.ptp(img[..., :3]) > 0.1  # not blank
    page = (rep / "report.html").read_text()
    assert page.count("<img") == 5 and "<table>" in page
    for link in links:
        assert f'src="{link}"' in page
    assert f"# Run report: {problem}" in md


def test_snapshot_indices_and_html() -> None:
    assert snapshot_indices(1) == [0]
    assert snapshot_indices(10) == [0, 3, 6, 9]
    h = markdown_to_html("# T\n\n| a | b |\n|---|---|\n| 1 | `x<y` |\n\n![c](f.png)\n")
    assert "<h1>T</h1>" in h and "<th>a</th>" in h and "<td><code>x&lt;y</code></td>" in h
    assert '<img alt="c" src="f.png"' in h


def test_reproduce_section_writes_document(tmp_path) -> None:
    from willmore_nlp.reproduce import reproduce

    doc = reproduce(tmp_path, only=["Fig. 2"])
    text = doc.read_text()
    assert "## Fig. 2" in text and "Regenerate with" in text
    for link in re.findall(r"\]\(([^)]+)\)", text):
        assert mpimg.imread(tmp_path / link).size > 0
    # the deviation quoted in the document is the computed one and small
    dev = float(re.search(r"exact radius: ([0-9.e+-]+)", text).group(1))
    assert 0 < dev < 1e-3
