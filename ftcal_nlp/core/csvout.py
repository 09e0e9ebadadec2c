"""Tables written as CSV without losing a bit: every float as the shortest text that reads back to the
same double (pyarrow's writer; ~10x faster than pandas' ``to_csv``, which at ``float_format="%.7g"``
put a time stamp of 1.6e9 s to the nearest 100 s). Integers as integers, NaN as an empty cell, the header
unquoted (quoted only where a name needs it). The file is written beside its target and renamed into
place, so a reader never sees half a table.
"""

from __future__ import annotations

import csv
import io
import os
import tempfile
from pathlib import Path

import pandas as pd
import pyarrow as pa
import pyarrow.csv as pacsv

__all__ = ["write_csv"]


def _header(columns) -> bytes:
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerow([str(c) for c in columns])
    return buf.getvalue().encode()


def write_csv(df: pd.DataFrame, path: str | Path) -> Path:
    """Write ``df`` (no index) to ``path`` at full precision (module docstring); returns the path."""
    path = Path(path)
    table = pa.Table.from_pandas(df, preserve_index=False)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(_header(df.columns))
            pacsv.write_csv(table, f, pacsv.WriteOptions(include_header=False))
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask
