"""Write a free-load simulation in the interchange format (``shared/DATA_FORMAT.md`` sections 2-5), with its truth.

Files: ``dataset.toml`` (one ``hanging`` recording, no ``gravity_body``: the
orientation columns give gravity per sample), ``robot.toml`` (``urdf`` and
``[transducers.X].link`` for a URDF leg; ``position_m`` and ``rotation`` for a
payload; no ``mass_kg``: there is no standing recording), ``{recording}.csv``
(every float at full precision: ``repr``, so a reader sees the simulator's
numbers bit for bit), ``robot.urdf`` (a copy, URDF legs) and ``truth.json``.
Its own small writer: the interchange reader (``data.py``) is not needed to
write a table.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from .config import FREE_SIM_KINDS, config_from_dict
from .simulate import FreeLoadResult, simulate_free


def free_load_files(res: FreeLoadResult) -> list[str]:
    """The names :func:`write_free_load` writes into its folder."""
    urdf = [res.robot["urdf"]] if res.urdf_text is not None else []
    return ["dataset.toml", "robot.toml", *urdf, *(e["file"] for e in res.manifest["recording"]), "truth.json"]


def write_free_load(res: FreeLoadResult, folder: str | Path, *, overwrite: bool = False) -> Path:
    """Write ``res`` into ``folder``; returns the manifest path. Nothing is written when
    ``dataset.toml`` exists and ``overwrite`` is false."""
    import tomli_w

    folder = Path(folder)
    manifest = folder / "dataset.toml"
    if manifest.exists() and not overwrite:
        raise FileExistsError(f"{manifest} exists; pass overwrite=True to replace it")
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "robot.toml").write_bytes(tomli_w.dumps(res.robot).encode())
    if res.urdf_text is not None:
        (folder / res.robot["urdf"]).write_text(res.urdf_text)
    for entry in res.manifest["recording"]:
        res.frame.to_csv(folder / entry["file"], index=False, float_format=None)  # None: repr, shortest round trip
    (folder / "truth.json").write_text(json.dumps(res.truth, indent=1))
    manifest.write_bytes(tomli_w.dumps(res.manifest).encode())
    return manifest


def simulate_to_folder(table: dict[str, Any], folder: str | Path, *, overwrite: bool = False) -> Path:
    """A ``[simulate]`` table -> a written dataset; returns the manifest path.

    ``kind = "payload" | "urdf_leg"`` goes to this package; no ``kind`` (or
    ``"hexapod"``) to the BigAnt simulator (:class:`ftcal_nlp.sim.SimConfig`).
    The files it writes over must be ones the tool wrote (``outdir.guard_files``: the folder's manifest lists
    them), and only with ``overwrite``; other files in the folder are left as they are.
    """
    from ...core.outdir import write_guarded

    kind = table.get("kind", "hexapod")
    if kind in FREE_SIM_KINDS:
        res = simulate_free(config_from_dict(table))
        names, write = free_load_files(res), lambda: write_free_load(res, folder, overwrite=True)
    elif kind != "hexapod":
        raise ValueError(f"[simulate] kind = {kind!r}; known kinds: {['hexapod', *sorted(FREE_SIM_KINDS)]}")
    else:
        from ..config import SimConfig
        from ..simulate import simulate
        from ..writer import simulation_files, write_simulation

        rest = {k: v for k, v in table.items() if k != "kind"}
        sim = simulate(SimConfig.from_dict(rest))
        names, write = simulation_files(sim), lambda: write_simulation(sim, folder, overwrite=True)
    return write_guarded(folder, names, write, force=overwrite)
