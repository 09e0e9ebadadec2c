"""What ``plan`` reads, once for every load: the input file (a protocol TOML, a ``robot.toml``, a pilot dataset, or
nothing: the default protocol), the ``--protocol`` file's ``[protocol]`` table, and which part plans it.

:func:`read_input` classifies the input by its keys (``DATA_FORMAT.md``): a manifest listing recordings is a pilot
dataset (read here, once; a free-load one when a transducer carries a free load, section 5); a ``robot.toml`` (``legs``
and ``transducers``) is a free-load robot with ``--protocol`` holds when it describes free loads (a ``urdf``, a
transducer ``link``, or no ``mass_kg``: a hexapod's has it, section 2) or the holds name free-load keys, and alone such
a robot is an error saying what to add; a protocol whose ``[protocol]`` has ``kind`` or names a ``robot`` is a
free-load protocol; everything else is a hexapod protocol (:mod:`.hexapod`). The ``--protocol`` file is read only
where its part needs it, so a pilot dataset's errors come before that file's.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from .. import config
from ..core.errors import ConfigError

#: which part plans an input: hexapod legs (hanging and standing, :mod:`.hexapod`) or free loads (:mod:`.free_load`)
HEXAPOD, FREE_LOAD = "hexapod", "free_load"
#: keys of a ``--protocol`` file that make a ``robot.toml`` a free-load one (holds, not a hexapod session)
FREE_LOAD_KEYS = ("holds", "orientations", "n_orientations", "transducer", "gravity_body", "robot")


class PlanError(ConfigError):
    """A protocol, robot, pilot or target that cannot be planned; the message names the file and key."""


def read_toml(path: Path) -> dict:
    """The table of a TOML file; a missing or invalid file is a :class:`PlanError` naming it."""
    return config.read_toml(path, PlanError, "file")


def protocol_table(protocol_file: str | Path | None) -> dict:
    """The ``[protocol]`` table of ``--protocol`` (the whole file when it has none; ``{}`` without the option)."""
    over = read_toml(Path(protocol_file)) if protocol_file else {}
    return over.get("protocol", over)


def is_free_robot(d: dict) -> bool:
    """A robot.toml that describes free loads (``DATA_FORMAT.md`` section 5): a URDF or a transducer ``link``, or no
    ``mass_kg`` (a hexapod's robot.toml has it: section 2)."""
    given = d.get("transducers")
    tables = given if isinstance(given, dict) else {}
    return "mass_kg" not in d or "urdf" in d or any(isinstance(t, dict) and "link" in t for t in tables.values())


@dataclass(frozen=True)
class PlanInput:
    """What to plan: ``family`` (:data:`HEXAPOD` or :data:`FREE_LOAD`), ``kind`` (``defaults``, ``dataset``, ``robot``
    or ``protocol``), the input and ``--protocol`` as given (None: not given), the pilot ``dataset`` (read) and, for a
    free load, the ``[protocol]`` ``table`` of holds."""

    family: str
    kind: str
    source: str | None
    protocol_file: str | None
    dataset: object = None
    table: dict | None = None


def read_input(path: str | None, protocol_file: str | None = None) -> PlanInput:
    """The input of ``plan`` classified (module docstring)."""
    if path is None:
        return PlanInput(HEXAPOD, "defaults", None, protocol_file)
    p = Path(path)
    d = read_toml(p)
    if "recording" in d or "recordings" in d:
        from ..core.data import read_dataset

        ds = read_dataset(p)
        return PlanInput(FREE_LOAD if ds.free_load_legs else HEXAPOD, "dataset", path, protocol_file, ds)
    if "legs" in d and "transducers" in d:   # a robot.toml
        over = protocol_table(protocol_file)
        if protocol_file and (is_free_robot(d) or any(k in over for k in FREE_LOAD_KEYS) or over.get("kind") in ("payload", "urdf")):
            return PlanInput(FREE_LOAD, "robot", path, protocol_file, table=over)
        if not protocol_file and is_free_robot(d):
            raise PlanError(
                f"{p}: a robot description (transducers {list(d['legs'])}) and no holds to plan: add a protocol of "
                f"holds, 'plan {p} --protocol HOLDS.toml' with HOLDS.toml holding [protocol] orientations = [[qw, qx, "
                "qy, qz], ...] (a payload's held orientations of B in W) or holds = [{quat = [qw, qx, qy, qz], q = {joint "
                "= rad, ...}}, ...] (joint poses of a URDF load or arm; gravity_body = [0, 0, -1] for a fixed level base "
                "instead of quat), hold_s, rate_hz, noise_force_N, noise_torque_Nm; or a protocol file whose [protocol] "
                f"names robot = \"{p.name}\"; or plan a recorded pilot, 'plan dataset.toml' (plan --help)",
                path=p, key="protocol")
    else:
        table = d.get("protocol", d)
        if isinstance(table, dict) and ("kind" in table or "robot" in table):
            return PlanInput(FREE_LOAD, "protocol", path, protocol_file, table=table)
    return PlanInput(HEXAPOD, "robot" if "transducers" in d and "mass_kg" in d else "protocol", path, protocol_file)
