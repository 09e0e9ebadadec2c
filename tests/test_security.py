"""No code runs from a data file, nothing is written outside -o, report.md carries no markup from names
(issue 24, item 6). The ingest map's names are tested with the other bad maps in ``test_ros.py``."""

import json
import re
from pathlib import Path

import pandas as pd
import pytest

from ftcal_nlp.core.calibration import Calibration, ModelName
from ftcal_nlp.core.errors import ConfigError
from ftcal_nlp.models import resolve
from ftcal_nlp.report.render import Code, Figure, Section, Table, Text, render_html, render_markdown

from conftest import require_sample


@pytest.fixture
def evil_calibration(tmp_path) -> tuple[Path, Path]:
    """A calibration.json whose model names a Python file that would leave a marker file when imported."""
    marker = tmp_path / "ran.txt"
    (tmp_path / "evil.py").write_text(f"open({str(marker)!r}, 'w').write('ran')\nclass Evil:\n    name = 'evil'\n    def build(self, ctx): pass\n")
    d = json.loads((require_sample() / "truth.json").read_text())
    d.update(g=9.81, model=f"{tmp_path / 'evil.py'}:Evil")
    cal = tmp_path / "calibration.json"
    cal.write_text(json.dumps(d))
    return cal, marker


def test_a_calibration_model_is_never_imported(evil_calibration):
    path, marker = evil_calibration
    cal = Calibration.load(path)
    assert isinstance(cal.model, ModelName) and isinstance(str(cal.model), ModelName)  # str() keeps the mark (pipeline)
    with pytest.raises(ConfigError, match=r"evil\.py:Evil' of a calibration file is not a registered name; known models: \['full'"):
        resolve(cal.model)
    assert not marker.exists()
    # the same text from the user's own config (a plain str) is the plug-in mechanism and still loads
    assert resolve(str.__str__(cal.model)).name == "evil" and marker.exists()
    # a registered name from a file is looked up as usual
    assert resolve(ModelName("trans6")).name == "trans6"


def test_diagnosis_of_an_offsets_only_run_falls_back_instead_of_importing(evil_calibration):
    """Offsets-only re-estimation copies the earlier calibration's model into the run: the diagnosis, which
    refits that model, uses 'full' with a warning rather than running the file."""
    from dataclasses import replace

    from ftcal_nlp.diagnose.core import _model_and_balance

    path, marker = evil_calibration
    prior = Calibration.load(path)
    run_cal = replace(prior, model=str(prior.model))  # what pipeline.calibrate does with it
    assert _model_and_balance(run_cal, None, None)[0] == "full" and not marker.exists()


def test_calibration_model_must_be_a_string(tmp_path):
    d = json.loads((require_sample() / "truth.json").read_text())
    d.update(g=9.81, model={"import": "os"})
    p = tmp_path / "c.json"
    p.write_text(json.dumps(d))
    with pytest.raises(ValueError, match=r"c\.json: key 'model' should be a model name"):
        Calibration.load(p)


def test_report_markdown_escapes_markup_from_names():
    bad = "<script>alert(1)</script>"
    img = "<img src=x onerror=alert(1)>"
    sec = Section(f"Leg {bad}", [Text(f"leg {bad} and `{bad}` in code & more"),
                                  Table(f"caption {img}", pd.DataFrame({"x": [1.0]}, index=pd.Index([img], name="leg"))),
                                  Code("```\n" + bad + "\n```"), Figure(f"walking_{bad}", None)])
    md = render_markdown("report", [sec])
    outside_code = md.replace(f"`{bad}`", "").replace("````\n```\n" + bad + "\n```\n````", "")
    for raw in ("<script", "<img"):
        assert not re.search(r"(?<!\\)" + raw, outside_code), md  # escaped (\\<), or inside code (literal there)
    assert "\\<script>" in md and "\\<img src=x" in md and "& more" in md and "&lt;" not in md
    # the code block's fence is longer than any backtick run inside it, so the name cannot close it
    assert "````\n```\n<script>" in md
    html = render_html("report", [sec])
    assert "<script" not in html and "<img src=x" not in html
