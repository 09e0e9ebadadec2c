"""The iCub yarpdatadumper converter (data/external/convert_icub_insitu.py) on synthetic dumper text: rows are the F/T
stamps unshifted, joints in rad interpolated to them, gravity from the level stance sole, the URDF load's mass and
the offsets recovered by a static fit of the written CSV, and the dataset reads (a mini biped URDF; < 5 s)."""

import importlib.util
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "data" / "external" / "convert_icub_insitu.py"


def _module():
    spec = importlib.util.spec_from_file_location("convert_icub_insitu", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_selftest(tmp_path):
    out = _module().selftest(tmp_path)
    assert out["rows"] == 1599
    assert abs(out["fit"]["mass"] - 2.0) < 1e-3


def test_read_state_first_group(tmp_path):
    p = tmp_path / "data.log"
    p.write_text("7 100.5 (1.0 2.0 3.0 4.0 5.0 6.0) [ok] (0 0 0 0 0 0) [ok]\n8 100.6 (1 2 3 4 5 7) [ok] (9 9 9 9 9 9) [ok]\n")
    t, q = _module().read_state(p)
    assert t.tolist() == [100.5, 100.6] and q[1].tolist() == [1, 2, 3, 4, 5, 7]
