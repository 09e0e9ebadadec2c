"""C source of a CasADi correction: the files ``export`` writes, for any calibration kind.

:func:`write_generated` runs CasADi's ``CodeGenerator`` on a function, appends the
hand-written wrapper (batch entry points) to the generated source and header, and
writes the ``USAGE.md`` beside them. ``export.py`` (hexapod ground wrenches) and
``export_loads.py`` (free loads' contact wrenches) build the function and the
wrapper; this module only writes them, so the two cannot drift apart.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import casadi as ca

__all__ = ["ExportedFiles", "write_generated"]


@dataclass(frozen=True)
class ExportedFiles:
    source: Path
    header: Path
    usage: Path


def write_generated(f: ca.Function, name: str, out_dir: Path, wrapper: tuple[str, str], usage_text: str) -> ExportedFiles:
    """Generate ``{name}.c``/``{name}.h`` of ``f`` in ``out_dir``, append ``wrapper`` = (source, header), write
    ``USAGE.md``."""
    out_dir.mkdir(parents=True, exist_ok=True)
    gen = ca.CodeGenerator(f"{name}.c", {"with_header": True})
    gen.add(f)
    gen.generate(str(out_dir) + "/")
    src, hdr = wrapper
    c_path, h_path = out_dir / f"{name}.c", out_dir / f"{name}.h"
    with c_path.open("a") as fh:
        fh.write(src)
    with h_path.open("a") as fh:
        fh.write(hdr)
    usage = out_dir / "USAGE.md"
    usage.write_text(usage_text)
    return ExportedFiles(c_path, h_path, usage)
