"""The run's report: labelled tables (no tuple headers, a row-label column, ``value ± se``), rendered
markup in report.html, the folds the text names, the diagnosis drawn by ``report/``, and the
matplotlib backend left to the entry points."""

from __future__ import annotations

import ast
import os
import re
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pandas as pd
import pytest

from ftcal_nlp import calibrate
from ftcal_nlp.report import build_sections, legs_as_columns, write_report
from ftcal_nlp.report.diagnosis import diagnosis_section
from ftcal_nlp.report.render import Table, inline_html, inline_md
from ftcal_nlp.core.results import Summary
from ftcal_nlp.core.settings import CalibrationSettings, DiagnoseSettings, SelectionSettings
from ftcal_nlp.sim import SimConfig, simulate

PACKAGE = Path(__file__).resolve().parents[1] / "ftcal_nlp"
FOLDS = 3  # not the default 5: the text must say what the settings did
TUPLE_HEADER = re.compile(r"\(\s*'[^']*'\s*,\s*'[^']*'\s*\)")


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    """A small simulated run (3-fold selection, a two-effect diagnosis) and its report folder."""
    sim = simulate(SimConfig.from_dict({"n_poses": 80, "hanging_cycles": 1.5, "walk_cycles": 0.5, "seed": 4}))
    settings = CalibrationSettings(selection=SelectionSettings(folds=FOLDS),
                                   diagnose=DiagnoseSettings(effects=("robot_mass", "offset_drift"), folds=3))
    res = replace(calibrate(sim.dataset, settings), truth=sim.truth)
    folder = tmp_path_factory.mktemp("report")
    write_report(res, folder)
    return res, folder


def _table_files(folder: Path, ext: str) -> list[Path]:
    files = sorted(p for p in folder.glob(f"*.{ext}") if p.name != "report.md")
    assert files, f"no .{ext} tables written"
    return files


def test_files_of_the_report(report):
    res, folder = report
    for stem in ("parameters", "model_selection", "hanging", "standing", "truth_check", "hanging_nlp_vs_baseline", "stage_times"):
        for ext in ("csv", "md", "tex"):
            assert (folder / f"{stem}.{ext}").is_file(), f"{stem}.{ext}"
    for fig in ("leg_com", "hanging_residuals", "naive_total", "total_residuals", "walking_walk", "diagnosis_shrinkage"):
        assert (folder / f"{fig}.png").stat().st_size > 5000, fig
    html = (folder / "report.html").read_text()
    assert html.count("data:image/png;base64,") >= 6


def test_no_tuple_headers_anywhere(report):
    _, folder = report
    for ext in ("md", "csv", "tex", "html"):
        for p in folder.glob(f"*.{ext}"):
            text = p.read_text()
            assert not TUPLE_HEADER.search(text), (p.name, TUPLE_HEADER.search(text).group(0))


def test_every_table_has_a_row_label_column(report):
    res, folder = report
    for p in _table_files(folder, "csv"):
        df = pd.read_csv(p)
        first = str(df.columns[0])
        assert first and not first.startswith("Unnamed"), (p.name, first)
        assert df[first].astype(str).str.len().gt(0).all(), p.name
    for p in _table_files(folder, "md"):
        head = next(l for l in p.read_text().splitlines() if l.startswith("|"))
        assert head.split("|")[1].strip(), (p.name, head)
    for p in _table_files(folder, "tex"):
        lines = p.read_text().splitlines()
        head = lines[lines.index("\\hline") + 1]
        assert head.split("&")[0].strip(), (p.name, head)
    # every table of every section, and every table of the stage summaries shown
    for sec in build_sections(res, folder / "again"):
        for block in sec.blocks:
            tables = [(block.caption, block.df)] if isinstance(block, Table) else block.tables if isinstance(block, Summary) else []
            for caption, df in tables:
                assert df.index.name, (sec.title, caption)
                assert not any(isinstance(c, tuple) for c in df.columns), (sec.title, caption)


def test_hanging_table_has_units_and_value_pm_se(report):
    res, folder = report
    df = pd.read_csv(folder / "hanging.csv", index_col=0)
    assert df.index.name == "parameter" and list(df.columns) == list(res.dataset.robot.legs)
    assert all(re.search(r"\[(N|N\*m)\]$", r) for r in df.index), list(df.index)
    assert df.map(lambda c: " ± " in c).all().all()


def test_one_value_and_error_style(report):
    _, folder = report
    for ext in ("md", "csv", "html"):
        for p in folder.glob(f"*.{ext}"):
            assert "+-" not in p.read_text(), p.name
    assert " ± " in (folder / "parameters.md").read_text() and " ± " in (folder / "report.html").read_text()
    for p in _table_files(folder, "tex"):
        text = p.read_text()
        assert "+-" not in text and "±" not in text, p.name
    assert "$\\pm$" in (folder / "parameters.tex").read_text()
    # one formatter, results.fmt_pm: no copy of it in report/
    assert not any("def fmt_pm" in p.read_text() for p in (PACKAGE / "report").glob("*.py"))


def test_html_has_no_literal_markup(report):
    _, folder = report
    html = (folder / "report.html").read_text()
    text = re.sub(r"data:image/png;base64,[A-Za-z0-9+/=]+", "", html)
    assert "`" not in text and "**" not in text
    assert "<code>" in text and "<b>" in text
    assert "<pre>" not in text  # summaries are tables, not preformatted text


def test_notation_section_comes_first(report):
    _, folder = report
    md = (folder / "report.md").read_text()
    titles = re.findall(r"^## (.+)$", md, flags=re.M)
    assert titles[:2] == ["Summary", "Notation"]
    notation = md.split("## Notation")[1].split("\n## ")[0]
    for term in ("w_o", "m_k g", "r_k(phi)", "R_tilde_k", "p'_k", "ft_k", "heading frame", "K-norm", "CV", "BIC", "±"):
        assert term in notation, term
    assert re.search(r"\*\*B\*\*", notation) and re.search(r"\*\*W\*\*", notation)


def test_folds_in_the_text_follow_the_settings(report):
    res, folder = report
    assert res.selection.folds == FOLDS
    for name in ("report.md", "report.html", "model_selection.md", "model_selection.tex"):
        text = (folder / name).read_text()
        assert f"{FOLDS}-fold" in text and "5-fold" not in text, name


def test_model_selection_table_has_no_duplicate_columns(report):
    res, folder = report
    for df in (pd.read_csv(folder / "model_selection.csv"), res.selection.report_table()):
        cols = [str(c) for c in df.columns]
        assert "name" not in cols and "dof" not in cols and cols.count("DOF") == 1, cols
    md = (folder / "model_selection.md").read_text()
    assert md.splitlines()[2].startswith("| Model | DOF | CV error")


def test_diagnosis_rendered_by_report(report, tmp_path):
    res, _ = report
    sec = diagnosis_section(res.diagnosis, tmp_path)
    assert sec.title and sec.text and len(sec.tables) == 3
    for name, path in sec.figures:
        assert path.is_file() and path.stat().st_size > 5000, name
    for df in (res.diagnosis.ranking_table(), res.diagnosis.kinds_table()):
        assert df.index.name


def test_diagnose_imports_neither_report_nor_matplotlib():
    for p in (PACKAGE / "diagnose").rglob("*.py"):
        tree = ast.parse(p.read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                mod = ("." * node.level) + (node.module or "")
                assert "report" not in mod and "matplotlib" not in mod, (p, mod)
            elif isinstance(node, ast.Import):
                assert not any("matplotlib" in a.name for a in node.names), p
    assert not (PACKAGE / "diagnose" / "figures.py").exists()


def test_matplotlib_backend_chosen_only_by_entry_points():
    users = sorted(str(p.relative_to(PACKAGE)) for p in PACKAGE.rglob("*.py") if "matplotlib.use(" in p.read_text())
    assert users == ["cli.py"], users  # cli.setup, which every command's main calls


def test_headless_without_mplbackend():
    env = {k: v for k, v in os.environ.items() if k not in ("MPLBACKEND", "DISPLAY", "WAYLAND_DISPLAY")}
    code = "import ftcal_nlp.report, matplotlib.pyplot as plt; print(plt.get_backend().lower())"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "agg"


def test_inline_markup():
    assert inline_html("a `x<y` and **b** +- c") == "a <code>x&lt;y</code> and <b>b</b> ± c"
    assert inline_md("from 1 N*m to 2 N*m") == "from 1 N\\*m to 2 N\\*m"  # two lone stars would pair into emphasis
    assert inline_md("torque [N*m]") == "torque [N*m]"
    assert inline_md("`a*b` **c**") == "`a*b` **c**"


def test_markdown_escapes_only_what_markdown_reads_as_markup(tmp_path):
    """Issue 30: ``->`` stayed ``-&gt;`` in report.md. Markdown gets backslash escapes where it would read markup
    (raw HTML, an entity, a block quote), no HTML entity anywhere; HTML escapes for HTML."""
    from ftcal_nlp.report.render import Figure, Section, Text, render_html, render_markdown

    assert inline_md("offset_drift -> clock_offset, a < b, a > b, R&D") == "offset_drift -> clock_offset, a < b, a > b, R&D"
    assert inline_md("<b>x</b> &amp; &#62;") == "\\<b>x\\</b> \\&amp; \\&#62;"
    assert inline_md("> not a quote") == "\\> not a quote"
    fig = tmp_path / "a<b> c.png"
    fig.write_bytes(b"\x89PNG\r\n")
    sec = Section("A -> B", [Text("drift -> creep & <i>x</i>"), Table("t -> u", pd.DataFrame({"a->b": [1.0]})),
                             Figure("f -> g", fig)])
    md = render_markdown("r -> s", [sec])
    assert "&gt;" not in md and "&lt;" not in md and "&amp;" not in md
    assert "## A -> B" in md and "drift -> creep & \\<i>x\\</i>" in md and "| a->b |" in md
    assert "](<a\\<b\\> c.png>)" in md
    html = render_html("r -> s", [sec])
    assert "drift -&gt; creep &amp; &lt;i&gt;x&lt;/i&gt;" in html and "<i>x" not in html


def test_legs_as_columns_spreads_lists_and_triples():
    df = pd.DataFrame({"residual RMS f [N]": ["0.05 0.06 0.07", "0.1 0.2 0.3"],
                       "tilt [deg]": ["a: 1 ± 0.1; b: 2 ± 0.1", "a: 3 ± 0.1; b: 4 ± 0.1"],
                       "converged": ["yes", "NO"]}, index=pd.Index(["FL", "FR"], name="leg"))
    out = legs_as_columns(df)
    assert list(out.columns) == ["FL", "FR"] and out.index.name == "quantity"
    assert list(out.index) == ["residual RMS f x [N]", "residual RMS f y [N]", "residual RMS f z [N]",
                               "tilt a [deg]", "tilt b [deg]", "converged"]
    assert out.loc["tilt b [deg]", "FR"] == "4 ± 0.1" and out.loc["residual RMS f z [N]", "FL"] == "0.07"
