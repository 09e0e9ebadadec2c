"""Plan a calibration session: the standard error each parameter group will have, before recording.

The one ``plan`` command for every load: the output checked (``outdir.check_file_output``: a ``.json`` file, not an
input, replaced only with ``--force``), the input read and classified (:func:`.reading.read_input`), the part of its
load planning it (:data:`PARTS`: ``plan_for`` of :mod:`.hexapod` or :mod:`.free_load`, each returning a plan with
``to_json_dict`` and ``text``), then ``plan.json`` written and the text printed, the same way for both.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
from typing import Any, Callable, Protocol

from . import free_load, hexapod
from .reading import FREE_LOAD, HEXAPOD, PlanInput, read_input


class Plan(Protocol):
    """What a part returns: a plan written as ``plan.json`` and printed."""

    def to_json_dict(self) -> dict: ...

    def text(self) -> str: ...


#: the part that plans each family of loads: ``plan_for(PlanInput, options) -> plan`` (``to_json_dict``, ``text``)
PARTS: dict[str, Callable[[PlanInput, Any], Plan]] = {HEXAPOD: hexapod.plan_for, FREE_LOAD: free_load.plan_for}

FREE_LOAD_HELP = """free loads (DATA_FORMAT.md section 5: wrist payloads, URDF loads, arms):
  plan dataset.toml                    a recorded pilot: each load fitted, the bound at its estimate on its samples,
                                       with its noise and the widening the run applies to serially correlated residuals
  plan robot.toml --protocol HOLDS.toml   the robot's transducers held as HOLDS.toml says
  plan HOLDS.toml                      the same, HOLDS.toml's [protocol] naming robot = "robot.toml"
HOLDS.toml:
  [protocol]
  transducer = "wrist"                 # default: every transducer of the robot.toml
  orientations = [[1, 0, 0, 0], ...]   # held orientations of B in W (qw, qx, qy, qz); or n_orientations, seed
  # or holds = [{quat = [qw, qx, qy, qz], q = {joint = rad}}, ...]: joint poses (URDF loads, arms); joints a hold does
  # not name are at 0; gravity_body = [0, 0, -1] (a fixed level base) for holds without quat
  hold_s = 5.0, rate_hz = 100.0, noise_force_N = 0.05, noise_torque_Nm = 0.003, mocap_jitter_deg = 0.0
  mass_kg = 1.0, com_m = [0, 0, 0.05]  # a rigid payload's expected mass and CoM in ft (a URDF load: the URDF's bodies)
  mount = true, gravity_tilt = true    # the mounting rotation and the world tilt estimated, as the run does
  temperature_range_C = 5.0            # the temperature range the session sweeps (a ramp): the temperature
                                       # coefficients' se and the range needed (plan/temperature.py); a pilot with
                                       # {X}_temp_C / temp_C gets them from its own temperature
  temperature_target_N_per_C = 0.001   # their target se (default: noise sd over a 10 degC working range)
  (ftcal_nlp/plan/free_load.py: the bound, the undetermined parameters named; white noise unless planned from a pilot)"""


def main(argv: list[str] | None = None, prog: str | None = None) -> int:
    from ..cli import add_common, guarded, parse, setup

    ap = argparse.ArgumentParser(prog=prog or "python -m ftcal_nlp.plan", description=__doc__.splitlines()[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=FREE_LOAD_HELP)
    ap.add_argument("input", nargs="?", help="protocol TOML, robot.toml, or a pilot dataset.toml (default: the default "
                    "hexapod protocol)")
    ap.add_argument("--protocol", help="protocol TOML: with a hexapod robot.toml or pilot, keys that change its protocol; "
                    "with a section-5 robot.toml, the holds to plan (below)")
    add_common(ap, output_help="plan file (default plan.json)", output_default="plan.json", old_force=("--overwrite",),
               force_help="overwrite the output")
    ap.add_argument("--search", action="store_true", help="search the shortest protocol meeting [targets]")
    ap.add_argument("--no-detection", action="store_true", help="skip the detection size of the library effects (~30 s)")
    ap.add_argument("--detect", nargs="+", metavar="EFFECT", help="detection size of these library effects only")
    ap.add_argument("--temperature-target", type=float, metavar="N_PER_DEGC", help="free loads: the se (N/degC of "
                    "force; torques the same multiple of their noise) the temperature coefficients should reach; the plan "
                    "says the temperature range needed (default: the noise sd over a 10 degC working range)")
    args = parse(ap, argv)
    setup(args)
    return guarded(lambda: _main(args), extra=(ValueError,))


def plan_inputs(args) -> dict[str, Path]:
    """What ``plan`` reads (``outdir.toml_inputs``: a pilot's files, a robot.toml's URDF, a protocol's robot.toml)."""
    from ..core.outdir import toml_inputs

    out: dict[str, Path] = {}
    if args.protocol:
        out.update(toml_inputs(Path(args.protocol), "protocol"))
    if args.input:
        out.update(toml_inputs(Path(args.input), "input"))
    return out


def _main(args) -> int:
    from ..core.outdir import check_file_output

    args.input = os.path.expanduser(args.input) if args.input else args.input
    args.protocol = os.path.expanduser(args.protocol) if args.protocol else args.protocol
    # the plan is JSON: a name of another type (.toml, .csv, .urdf) is refused, not given JSON bytes
    out = check_file_output(args.output, plan_inputs(args), force=args.force, suffixes=(".json",))
    inp = read_input(args.input, args.protocol)
    plan = PARTS[inp.family](inp, args)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(plan.to_json_dict(), indent=1, default=float))
    if not args.quiet:
        print(plan.text())
        print(f"wrote {out}")
    return 0

