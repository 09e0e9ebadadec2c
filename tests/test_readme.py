"""The README is a user's guide: short, and every file, config and command it names exists.

Method notes live in ``docs/``, results in ``reports/bench/README.md``, history in ``CHANGELOG.md``
(issue 31); a README that grows past its budget or names a file that was moved or renamed fails here.
"""

from __future__ import annotations

import re
from pathlib import Path

from ftcal_nlp.cli import COMMANDS

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
MAX_LINES = 400

# Paths inside the repository the README may name. Output folders (``reports/sample/``, ``data/bigant_sim/``)
# are what a run writes, so only the committed parts of ``reports/`` are checked.
CHECKED = re.compile(
    r"(?<![\w./-])((?:problems|tests|docs|ftcal_nlp)/[\w./*-]*[\w/*]|CHANGELOG\.md|"
    r"reports/bench/README\.md|reports/reference/[\w./*-]*[\w/*])"
)


def named_paths(text: str) -> set[str]:
    """Every repository path (or glob) of the checked folders that ``text`` names (trailing full stop dropped)."""
    return {m.rstrip("./") if m.endswith(".") else m for m in CHECKED.findall(text)}


def test_readme_within_budget():
    n = len(README.read_text(encoding="utf-8").splitlines())
    assert n <= MAX_LINES, f"README.md has {n} lines; the user's guide keeps to {MAX_LINES} (method notes go to docs/)"


def test_readme_paths_exist():
    paths = named_paths(README.read_text(encoding="utf-8"))
    assert any(p.startswith("problems/") and p.endswith(".toml") for p in paths)
    assert any(p.startswith("tests/") for p in paths)
    missing = sorted(p for p in paths if not any(ROOT.glob(p.rstrip("/"))))
    assert not missing, f"README.md names paths that do not exist: {missing}"


def test_readme_names_every_command():
    text = README.read_text(encoding="utf-8")
    listed = set(re.findall(r"^\| `(\w+) ", text, flags=re.M))
    assert listed == set(COMMANDS), f"README commands {sorted(listed)} != the CLI's {sorted(COMMANDS)}"


def test_named_paths_reads_what_a_sentence_names():
    text = ("see `problems/sample.toml`, tests/test_outdir.py. and docs/method.md; reports/sample/ and "
            "reports/bench/README.md, problems/sample*.toml, not myproblems/x.toml")
    assert named_paths(text) == {"problems/sample.toml", "tests/test_outdir.py", "docs/method.md",
                                 "reports/bench/README.md", "problems/sample*.toml"}
