"""The house's layers (docs/architecture.md): every import of the package runs to its own layer or below, and no
private name is imported across packages. Function-local and TYPE_CHECKING imports count too."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent / "ftcal_nlp"

#: layer -> top-level modules and folders of ftcal_nlp (docs/architecture.md's table)
LAYERS = {
    6: ("run", "plan", "export", "holdout", "ingest", "bench", "__init__"),
    5: ("pipeline", "calibration_run", "report"),
    4: ("correct", "diagnose", "crb"),
    3: ("estimate", "sim", "ros", "cli"),
    2: ("loads", "models", "effects", "truth", "config"),
    1: ("core",),
}
LAYER_OF = {name: k for k, names in LAYERS.items() for name in names}


def _imports():
    """(file, line, importing module's dotted name, imported module's dotted name, imported names)."""
    for f in sorted(PACKAGE.rglob("*.py")):
        parts = list(f.relative_to(PACKAGE.parent).with_suffix("").parts)
        package = parts[:-1]
        me = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        for node in ast.walk(ast.parse(f.read_text())):
            if not isinstance(node, ast.ImportFrom):
                continue
            if node.level:
                base = package[: len(package) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target == "ftcal_nlp":
                for a in node.names:
                    yield f, node.lineno, me, f"ftcal_nlp.{a.name}", ()
            elif target.startswith("ftcal_nlp."):
                yield f, node.lineno, me, target, tuple(a.name for a in node.names)


def _top(dotted: str) -> str:
    parts = dotted.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def test_every_top_level_module_and_folder_has_a_layer():
    names = {p.stem if p.is_file() else p.name for p in PACKAGE.iterdir()
             if (p.suffix == ".py" or (p.is_dir() and (p / "__init__.py").exists())) and p.stem != "__main__"}
    assert names == set(LAYER_OF), (sorted(names - set(LAYER_OF)), sorted(set(LAYER_OF) - names))


def test_imports_run_downward_only():
    up = []
    for f, line, me, target, _ in _imports():
        if me == "ftcal_nlp.__main__":
            continue   # the package's entry point (python -m ftcal_nlp): nothing imports it
        a, b = LAYER_OF[_top(me)], LAYER_OF[_top(target)]
        if b > a:
            up.append(f"{f.relative_to(PACKAGE.parent)}:{line}: {me} (layer {a}) imports {target} (layer {b})")
    assert not up, "\n".join(up)


def test_no_private_name_is_imported_across_packages():
    found = []
    for f, line, me, target, names in _imports():
        here = me if f.name == "__init__.py" else me.rsplit(".", 1)[0]
        there = target.rsplit(".", 1)[0]
        for n in names:
            if n.startswith("_") and not n.startswith("__") and here != there and here != target:
                found.append(f"{f.relative_to(PACKAGE.parent)}:{line}: {n} from {target}")
    assert not found, "\n".join(found)
