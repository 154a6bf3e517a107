"""MkDocs hooks: pages generated from the code and the committed reports, never written by hand.

* ``reference/cli.md``: the help of every ``willmore-nlp`` subcommand, taken from the argparse parser
  (:func:`willmore_nlp.cli.build_parser`), replacing the marker ``<!-- generated:cli -->``.
* ``reference/options.md``: the flow options (:class:`willmore_nlp.settings.FlowSettings`) and every solver's
  options, with default, allowed values and the meaning from their docstrings, replacing ``<!-- generated:options -->``.
* ``reference/problems.md``: the registered problems with their parameters and defaults
  (:func:`willmore_nlp.registry.load_all`), replacing ``<!-- generated:problems -->``.
* ``evidence/*.md``: the measured studies committed in ``reports/`` (anisotropy, boundaries, scale,
  vesicles).
* ``gallery/index.md``: every section of ``reports/REPRODUCTION.md`` (heading, verdicts, figures),
  replacing ``<!-- generated:gallery -->``; the figures of ``reports/figures`` are added to the site.
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path
from typing import Any

from mkdocs.structure.files import File, Files

ROOT = Path(__file__).resolve().parent.parent
REPORTS = ROOT / "reports"
FIGURES = REPORTS / "figures"
GALLERY_FIGURES = "gallery/figures"


def _subcommands(parser: argparse.ArgumentParser) -> list[tuple[str, str, argparse.ArgumentParser]]:
    """(name, one-line help, parser) of every subcommand, in the parser's order."""
    out = []
    for action in parser._actions:  # argparse exposes subparsers only through its actions
        if isinstance(action, argparse._SubParsersAction):
            helps = {a.dest: a.help or "" for a in action._choices_actions}
            out += [(name, helps.get(name, ""), sub) for name, sub in action.choices.items()]
    return out


def _argument_rows(parser: argparse.ArgumentParser) -> list[str]:
    rows = ["| argument | meaning | default |", "|---|---|---|"]
    for a in parser._actions:
        if isinstance(a, argparse._HelpAction | argparse._SubParsersAction):
            continue
        name = ", ".join(f"`{s}`" for s in a.option_strings) or f"`{a.metavar or a.dest}`"
        if a.option_strings and a.nargs != 0:
            name += f" `{a.metavar or a.dest.upper()}`"
        meaning = (a.help or "").replace("|", "\\|")
        if a.choices:
            meaning += " (one of " + ", ".join(f"`{c}`" for c in a.choices) + ")"
        default = "" if a.default in (None, False, argparse.SUPPRESS) else f"`{a.default}`"
        rows.append(f"| {name} | {meaning} | {default} |")
    return rows


def cli_markdown() -> str:
    """Markdown reference of the ``willmore-nlp`` command line, generated from its parser."""
    from willmore_nlp.cli import build_parser

    parser = build_parser()
    parts = ["```text", parser.format_usage().strip(), "```", "", *_argument_rows(parser), ""]
    for name, help_text, sub in _subcommands(parser):
        parts += [f"## `willmore-nlp {name}`", "", help_text[:1].upper() + help_text[1:] + ".", "",
                  "```text", sub.format_usage().strip(), "```", "", *_argument_rows(sub), ""]
    return "\n".join(parts)


def _documented(cls: type) -> dict[str, str]:
    """Field name -> its meaning in the numpy docstring of ``cls`` (Attributes section); every field must have one."""
    import dataclasses
    import inspect

    import griffe

    sections = griffe.Docstring(inspect.getdoc(cls) or "").parse("numpy", warn_missing_types=False)
    meaning = {p.name: " ".join(p.description.split()).replace("|", "\\|") for sec in sections
               if sec.kind.value == "attributes" for p in sec.value}
    missing = [f.name for f in dataclasses.fields(cls) if f.name not in meaning]
    if missing:
        raise ValueError(f"{cls.__name__}: options without a meaning in its docstring: {missing}")
    return meaning


def _settings_rows(cls: type) -> list[str]:
    meaning = _documented(cls)
    rows = ["| key | default | allowed | meaning |", "|---|---|---|---|"]
    for key, kind in cls.kinds().items():
        rows.append(f"| `{key}` | `{cls.defaults()[key]!r}` | {kind.what} | {meaning[key]} |")
    return rows


def flow_options_markdown() -> str:
    """Tables of the flow options and of every solver's options, generated from the settings classes."""
    from willmore_nlp.settings import FlowSettings
    from willmore_nlp.solvers import solver_names, solver_settings
    from willmore_nlp.solvers.ipopt import IPOPT_DEFAULTS

    parts = [*_settings_rows(FlowSettings), "", "## Solver options", "",
             "Given like the flow options; each solver refuses options it does not know (`warm_start` and "
             "`print_level` are accepted by every solver).", ""]
    for name in solver_names():
        cls = solver_settings(name)
        if name == "ipopt":
            parts += ["### `ipopt`", "", "`warm_start` (default `False`): start each step from the previous "
                      "step's multipliers. Any IPOPT option as `ipopt.NAME` (in Python also as one mapping, "
                      "`ipopt={\"max_iter\": 10}`; IPOPT's also when it is the first-step, fallback or large "
                      "solver; `tol`, `max_iter`, `print_level` also without the prefix when IPOPT is `solver`), "
                      "checked against IPOPT's documented type and range before anything runs. Defaults "
                      "differing from IPOPT's:", "", "| IPOPT option | default |", "|---|---|",
                      *(f"| `{k}` | `{v!r}` |" for k, v in IPOPT_DEFAULTS.items()), ""]
        elif cls.kinds():
            parts += [f"### `{name}`", "", *_settings_rows(cls), ""]
        else:
            parts += [f"### `{name}`", "", (cls.__doc__ or "").strip().splitlines()[0], ""]
    return "\n".join(parts)


def problems_markdown() -> str:
    """Markdown list of the registered problems with their parameters and defaults."""
    from willmore_nlp.registry import load_all

    parts = []
    for name, entry in sorted(load_all().items()):
        parts += [f"## `{name}`", "", entry.description, "", "| parameter | default |", "|---|---|"]
        parts += [f"| `{k}` | `{v!r}` |" for k, v in entry.defaults().items()]
        parts.append("")
    return "\n".join(parts)


def gallery_markdown() -> str:
    """The reproduction's sections: heading, verdict paragraphs and figures (links into the site)."""
    text = (REPORTS / "REPRODUCTION.md").read_text(encoding="utf-8")
    sections = re.split(r"^## ", text, flags=re.M)[1:]
    parts = []
    for sec in sections:
        lines = sec.splitlines()
        parts += [f"## {lines[0]}", ""]
        for ln in lines[1:]:
            if ln.startswith(("**Paper:**", "**Verdict", "**Comment:**")):
                parts += [ln, ""]
            for alt, src in re.findall(r"!\[([^\]]*)\]\(figures/([^)]+)\)", ln):
                parts += [f"![{alt}](figures/{src})", ""]
    return "\n".join(parts)


GENERATED = {
    "reference/cli.md": ("<!-- generated:cli -->", cli_markdown),
    "reference/options.md": ("<!-- generated:options -->", flow_options_markdown),
    "reference/problems.md": ("<!-- generated:problems -->", problems_markdown),
    "gallery/index.md": ("<!-- generated:gallery -->", gallery_markdown),
}


EVIDENCE = ("anisotropic_study.md", "boundary_study.md", "benchmark_scale.md", "benchmark_control.md",
            "vesicle_evolver.md", "genus2_handles_study.md")
"""Measured studies of ``reports/`` shown under ``evidence/`` as they are committed."""


def on_files(files: Files, config: Any, **kwargs: Any) -> Files:
    """Add the committed figures of ``reports/figures`` under ``gallery/figures``, and the measured
    studies of ``reports/`` (with the images they show) under ``evidence/``."""
    for png in sorted(FIGURES.glob("*.png")):
        files.append(File.generated(config, f"{GALLERY_FIGURES}/{png.name}", abs_src_path=str(png)))
    for name in EVIDENCE:
        files.append(File.generated(config, f"evidence/{name}", abs_src_path=str(REPORTS / name)))
    for png in sorted(REPORTS.glob("*.png")):
        files.append(File.generated(config, f"evidence/{png.name}", abs_src_path=str(png)))
    return files


def on_page_markdown(markdown: str, page: Any, config: Any, files: Files, **kwargs: Any) -> str:
    """Replace the marker of a generated page by its generated content."""
    entry = GENERATED.get(page.file.src_uri)
    if entry is None:
        return markdown
    marker, make = entry
    if marker not in markdown:
        raise ValueError(f"{page.file.src_uri}: marker {marker} missing")
    return markdown.replace(marker, make())
