"""``calibration_with_effect.json`` after the hexapod chain (issue 23, item 2): several effects fitted together.

The block (``meta.effect``, ``JointRefit.effect_block``) of a joint refit of several effects (``Combined``) names them
``"a+b"`` and lists each in ``members`` with its slice of the joint ``eta``; ``correct`` applies every member
(``Combined.correct``):

* a synthetic block applied at once equals its members applied one by one by hand (single-effect blocks): in
  sequence where the corrections are shifts (casing load, offset drift, the motion-capture bias on the orientations),
  and as the sum of the members' corrections of the recorded readings where one depends on the readings (gain and
  crosstalk: the nested sequence differs by the second-order product the fit did not have); the covariance is
  ``J Sigma J^T`` of the joint ``eta_cov`` (cross-member terms included; ``J`` by finite differences here) plus the
  drift's rate variance;
* a single-effect file as older versions wrote it (no ``members``) applies as before (the units' formulas);
* bad blocks give a ValueError naming the key;
* end to end (``test_hexchain.py::test_two_effects_are_both_named_with_parameters``, its
  ``_check_the_chains_calibration_corrects_a_walk``): a small simulated session with a casing load and an offset drift;
  the chain names both, and the corrected walk with the chain's last joint refit is closer to the truth than with the
  first link's. It ran here on its own smaller session of the same two effects; test_hexchain.py's run of them (the
  whole library) checks the same, with one calibrate() instead of two.
"""

from __future__ import annotations

import copy
import re

import numpy as np
import pytest

from ftcal_nlp.core.calibration import Calibration
from ftcal_nlp.diagnose.refit import JointRefit, combined_members
from ftcal_nlp.effects.correction import apply_effect, correct_for_effect
from ftcal_nlp.effects import EFFECTS, AugContext
from ftcal_nlp.effects.combined import Combined
from ftcal_nlp.effects.injection import HOUR_S
from ftcal_nlp.core.geometry import cayley, rotvec_to_rotation
from ftcal_nlp.sim import SimConfig, simulate

WRENCH = ("fx", "fy", "fz", "tx", "ty", "tz")
T_REF = 500.0


@pytest.fixture(scope="module")
def tiny():
    sim = simulate(SimConfig.from_dict({"n_poses": 12, "hanging_cycles": 0.5, "walk_cycles": 0.2, "seed": 3}))
    return sim.truth, np.asarray(sim.dataset.robot.nominal_rotations(), float)


def _with(truth: Calibration, block: dict) -> Calibration:
    return Calibration(truth.legs, truth.mass_kg, truth.g, truth.model, truth.com_body_m, {"effect": copy.deepcopy(block)})


def _samples(seed: int, K: int, N: int = 11):
    rng = np.random.default_rng(seed)
    w = rng.normal(size=(N, K, 6))
    phi = rng.uniform(0, 2 * np.pi, (N, K))
    R = rotvec_to_rotation(rng.normal(scale=0.2, size=(N, 3)))
    return w, phi, R, np.linspace(0.0, 7200.0, N)


def _joint_block(units, truth: Calibration, R_nom: np.ndarray, seed: int) -> tuple[dict, np.ndarray, np.ndarray]:
    """The block a joint refit of ``units`` writes (``JointRefit.effect_block``), with random parameters: standing
    ``eta`` (and the offset shift where a member shifts offsets), a covariance with cross-member terms, drift rates."""
    rng = np.random.default_rng(seed)
    both = Combined(units)
    ctx = AugContext.from_calibration(truth, truth.leg_names, R_nom)
    names = list(both.standing_params(ctx).names) + ([f"dw_o.{c} [B]" for c in WRENCH] if both.shifts_offsets else [])
    m = len(names)
    eta = rng.normal(scale=0.5, size=m)
    A = rng.normal(size=(m, m))
    cov = 0.02 * (A @ A.T / m + 0.1 * np.eye(m))             # full: every pair of parameters correlated
    se = np.sqrt(np.diag(cov))
    params = {}
    if any(u.name == "offset_drift" for u in units):          # the hanging face's rates (what the drift corrects with)
        params.update({f"hanging:offset_drift:{k}.{c}/h": (float(rng.normal()), float(rng.uniform(0.1, 0.3)))
                       for k in truth.leg_names for c in WRENCH})
    params.update({n: (float(v), float(s)) for n, v, s in zip(names, eta, se)})
    jr = JointRefit(both.name, {}, None, params, eta, T_REF, (), both.variant, cov, combined_members(both, ctx, params))
    return {**jr.effect_block(), "R_nominal": R_nom.tolist()}, eta, cov


def _single(block: dict, i: int) -> dict:
    """Member ``i`` written by hand as a single effect's block (the layout older versions wrote)."""
    mb = block["members"][i]
    a, b = mb["eta_slice"]
    C = np.asarray(block["eta_cov"])[a:b, a:b]
    return {"name": mb["name"], "variant": mb["variant"], "eta": mb["eta"], "t_ref_s": block["t_ref_s"], "eta_cov": C.tolist(),
            "parameters": mb["parameters"], "R_nominal": block["R_nominal"]}


def test_the_block_lists_every_member_with_its_slice(tiny):
    truth, R_nom = tiny
    units = [EFFECTS["casing_load"], type(EFFECTS["offset_drift"])(degree=2, hanging="cubic"), EFFECTS["mocap_bias"]]
    block, eta, _ = _joint_block(units, truth, R_nom, 0)
    ctx = AugContext.from_calibration(truth, truth.leg_names, R_nom)
    assert block["name"] == "casing_load+offset_drift+mocap_bias"
    assert [m["name"] for m in block["members"]] == ["casing_load", "offset_drift", "mocap_bias"]
    c0 = 0
    for u, mb in zip(units, block["members"]):
        m = u.standing_params(ctx).m
        assert mb["eta_slice"] == [c0, c0 + m] and mb["eta"] == eta[c0 : c0 + m].tolist() and mb["variant"] == u.variant
        assert all(":" not in n.removeprefix("hanging:") for n in mb["parameters"]), mb["parameters"]   # prefix taken off
        assert len(mb["parameters"]) == m + (6 * len(truth.leg_names) if u.name == "offset_drift" else 0)
        c0 += m
    assert c0 == len(eta) - 6          # the offset shift follows the members' parameters
    assert block["members"][1]["parameters"][f"hanging:{truth.leg_names[2]}.fz/h"]["se"] > 0
    assert "members" not in JointRefit("casing_load", {}, None, {}, eta[:4], 0.0).effect_block()   # one effect: as before
    # a single effect is one whatever its variant looks like (no guess from the name)
    assert "members" not in JointRefit("casing_load", {}, None, {}, eta[:4], 0.0, variant={"casing_load": {}}).effect_block()


def test_a_parameter_the_poses_do_not_determine_leaves_the_components_it_moves_without_a_finite_se(tiny):
    """``eta_undetermined``: the components a face moves through an undetermined parameter get an infinite variance;
    the others keep ``J Sigma J^T`` (the pseudo-inverse's rows of that parameter are no variance)."""
    truth, R_nom = tiny
    units = [EFFECTS["gain_crosstalk"], EFFECTS["casing_load"]]
    block, _, _ = _joint_block(units, truth, R_nom, 4)
    w, phi, R, t = _samples(4, len(truth.leg_names), N=5)
    _, _, cov0 = correct_for_effect(_with(truth, block), 30.0 * w, phi, R, t)
    J = _finite_jacobian(truth, block, 30.0 * w, phi, R, t)
    j = int(np.argmax(np.abs(J).sum(axis=(0, 1, 2))))     # a parameter that moves some components
    und = [False] * len(block["eta"])
    und[j] = True
    _, _, cov1 = correct_for_effect(_with(truth, {**block, "eta_undetermined": und}), 30.0 * w, phi, R, t)
    moved = np.abs(J[..., j]) > 0
    diag1, diag0 = np.diagonal(cov1, axis1=2, axis2=3), np.diagonal(cov0, axis1=2, axis2=3)
    assert moved.any() and (~moved).any()
    assert np.all(np.isinf(diag1[moved])) and np.array_equal(diag1[~moved], diag0[~moved])


def test_shifts_and_the_mocap_bias_applied_at_once_equal_the_members_in_sequence(tiny):
    truth, R_nom = tiny
    units = [EFFECTS["casing_load"], EFFECTS["offset_drift"], EFFECTS["mocap_bias"]]
    block, _, _ = _joint_block(units, truth, R_nom, 1)
    w, phi, R, t = _samples(1, len(truth.leg_names))
    w_all, R_all, cov_all = correct_for_effect(_with(truth, block), w, phi, R, t)
    # by hand, one member after the other, each from its own single-effect block
    w1, R1, c1 = correct_for_effect(_with(truth, _single(block, 0)), w, phi, R, t)
    w2, R2, c2 = correct_for_effect(_with(truth, _single(block, 1)), w1, phi, R1, t)
    w3, R3, c3 = correct_for_effect(_with(truth, _single(block, 2)), w2, phi, R2, t)
    np.testing.assert_allclose(w_all, w3, rtol=0, atol=1e-12)
    np.testing.assert_allclose(R_all, R3, rtol=0, atol=1e-12)
    assert np.array_equal(w3, w2) and not np.allclose(R3, R)     # the bias moved the orientations only
    q = np.asarray(block["members"][2]["eta"])
    np.testing.assert_allclose(np.einsum("nji,j->ni", R_all, [0, 0, 1.0]), np.einsum("ij,nj->ni", cayley(0.01 * q), R[:, 2, :]),
                               atol=1e-12)
    # the drift: w - D (t - t_ref) / 1 h per leg, D the member's hanging rates
    legs = truth.leg_names
    D = np.array([[block["members"][1]["parameters"][f"hanging:{k}.{c}/h"]["value"] for c in WRENCH] for k in legs])
    np.testing.assert_allclose(w2 - w1, -((t - T_REF) / HOUR_S)[:, None, None] * D[None], atol=1e-12)
    # covariance: the casing load's face (its own block of eta_cov: it is the only face member) plus the drift's
    assert c3 is None or not np.any(c3)    # the bias leaves the readings: their covariance gets nothing from it
    assert np.any(c1) and np.any(c2)
    np.testing.assert_allclose(cov_all, c1 + c2, rtol=1e-12, atol=1e-15)


def _finite_jacobian(truth, block, w, phi, R, t, h: float = 1e-6) -> np.ndarray:
    """d w' / d eta (N, K, 6, m) of the block's correction, by central differences over the joint eta (and the
    members' slices with it)."""
    eta = np.asarray(block["eta"], float)
    J = np.zeros(w.shape + (len(eta),))
    for j in range(len(eta)):
        out = []
        for s in (h, -h):
            b = copy.deepcopy(block)
            b["eta"] = (eta + s * np.eye(len(eta))[j]).tolist()
            for mb in b["members"]:
                mb["eta"] = b["eta"][mb["eta_slice"][0] : mb["eta_slice"][1]]
            out.append(apply_effect(_with(truth, b), w, phi, R, t)[0])
        J[..., j] = (out[0] - out[1]) / (2 * h)
    return J


def test_readings_dependent_members_add_up_and_their_covariance_has_the_cross_terms(tiny):
    truth, R_nom = tiny
    units = [EFFECTS["gain_crosstalk"], EFFECTS["casing_load"]]
    block, _, cov = _joint_block(units, truth, R_nom, 2)
    w, phi, R, t = _samples(2, len(truth.leg_names), N=5)
    w = 30.0 * w          # readings of tens of N: the gain's Jacobian (0.01 (w - w_o)) is as large as the casing load's
    w_all, R_all, cov_all = correct_for_effect(_with(truth, block), w, phi, R, t)
    wg, _, cg = correct_for_effect(_with(truth, _single(block, 0)), w, phi, R, t)
    wc, _, cc = correct_for_effect(_with(truth, _single(block, 1)), w, phi, R, t)
    # the fitted model: each member corrects the recorded readings, the corrections add up
    np.testing.assert_allclose(w_all, w + (wg - w) + (wc - w), rtol=0, atol=1e-12)
    assert np.array_equal(R_all, R)
    # the nested sequence (gain applied to readings the casing load corrected) differs by the second-order product
    nested = correct_for_effect(_with(truth, _single(block, 0)), wc, phi, R, t)[0]
    assert np.max(np.abs(nested - w_all)) > 1e-4
    # covariance: J Sigma J^T of the joint eta_cov, cross-member terms included
    J = _finite_jacobian(truth, block, w, phi, R, t)
    want = np.einsum("nkam,mq,nkbq->nkab", J, cov, J)
    np.testing.assert_allclose(cov_all, want, rtol=1e-6, atol=1e-10)
    cross = cov_all - cg - cc            # what the members' own blocks of eta_cov leave out
    assert np.max(np.abs(cross)) > 0.05 * np.max(np.abs(cov_all))


def test_an_old_single_effect_file_applies_as_before(tiny, tmp_path):
    """A block without ``members`` (written by older versions), saved and read back: the units' formulas."""
    truth, R_nom = tiny
    legs, K = truth.leg_names, len(truth.leg_names)
    w, phi, R, t = _samples(3, K)
    rng = np.random.default_rng(3)
    eta, s = rng.normal(size=4 * K), rng.uniform(0.1, 1.0, 4 * K)
    old = {"name": "casing_load", "variant": {"harmonics": 1}, "eta": eta.tolist(), "t_ref_s": 0.0, "eta_cov": np.diag(s**2).tolist(),
           "parameters": {}, "R_nominal": R_nom.tolist()}
    path = tmp_path / "calibration_with_effect.json"
    _with(truth, old).save(path)
    cal = Calibration.load(path)
    w2, R2, C = correct_for_effect(cal, w, phi, R, t)
    a, v = eta.reshape(K, 4), s.reshape(K, 4) ** 2
    expect = w.copy()
    expect[..., 0] -= a[None, :, 0] * np.cos(phi) + a[None, :, 1] * np.sin(phi)
    expect[..., 1] -= a[None, :, 2] * np.cos(phi) + a[None, :, 3] * np.sin(phi)
    np.testing.assert_allclose(w2, expect, atol=1e-12)
    assert np.array_equal(R2, R)
    np.testing.assert_allclose(C[..., 0, 0], np.cos(phi) ** 2 * v[None, :, 0] + np.sin(phi) ** 2 * v[None, :, 1], rtol=1e-10)
    drift = {"name": "offset_drift", "variant": {"degree": 2, "hanging": "cubic"}, "eta": [0.0] * 12, "t_ref_s": 100.0,
             "parameters": {f"hanging:{legs[1]}.fy/h": {"value": 2.0, "se": 0.5}}}
    _with(truth, drift).save(path)
    w3, _, C3 = correct_for_effect(Calibration.load(path), w, phi, R, t)
    th = (t - 100.0) / HOUR_S
    dw = w3 - w
    np.testing.assert_allclose(dw[:, 1, 1], -2.0 * th, atol=1e-12)
    assert np.count_nonzero(dw[:, [0, 2, 3, 4, 5]]) == 0 and np.count_nonzero(dw[:, 1, [0, 2, 3, 4, 5]]) == 0
    np.testing.assert_allclose(C3[:, 1, 1, 1], (0.5 * th) ** 2, atol=1e-15)


def test_a_combined_file_reads_back_and_applies_the_same(tiny, tmp_path):
    truth, R_nom = tiny
    block, _, _ = _joint_block([EFFECTS["casing_load"], EFFECTS["offset_drift"]], truth, R_nom, 4)
    w, phi, R, t = _samples(4, len(truth.leg_names))
    path = tmp_path / "calibration_with_effect.json"
    _with(truth, block).save(path)
    a = correct_for_effect(_with(truth, block), w, phi, R, t)
    b = correct_for_effect(Calibration.load(path), w, phi, R, t)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)


def _bad(block: dict, change) -> dict:
    b = copy.deepcopy(block)
    change(b)
    return b


BAD = {
    "unknown member": (lambda b: b["members"][1].update(name="no_such_effect"), "meta.effect.members[1].name"),
    "name mismatch": (lambda b: b.update(name="casing_load+gain_crosstalk"), "meta.effect.name"),
    "member eta not its slice": (lambda b: b["members"][0].update(eta=b["members"][0]["eta"][:-1]), "meta.effect.members[0].eta"),
    "member eta of the wrong size": (lambda b: (b["members"][0].update(eta_slice=[0, 3], eta=b["eta"][:3]),
                                                b["members"][1].update(eta_slice=[3, 3 + len(b["members"][1]["eta"])],
                                                                       eta=b["eta"][3 : 3 + len(b["members"][1]["eta"])])),
                                     "meta.effect.members[0].eta has 3 values"),
    "slice out of range": (lambda b: b["members"][1].update(eta_slice=[0, 10**4]), "meta.effect.members[1].eta_slice"),
    "joint eta too short": (lambda b: b.update(eta=b["eta"][:5]), "eta_slice"),
    "eta_cov not square": (lambda b: b.update(eta_cov=[[1.0, 0.0]]), "meta.effect.eta_cov"),
    "members not a list": (lambda b: b.update(members={"casing_load": {}}), "meta.effect.members"),
    "a member twice": (lambda b: (b["members"].__setitem__(1, copy.deepcopy(b["members"][0])), b.update(name="casing_load+casing_load")),
                       "meta.effect.members"),
    "bad variant": (lambda b: b["members"][0].update(variant={"no_such_key": 1}), "meta.effect.members[0].variant"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_blocks_name_the_key(tiny, case):
    truth, R_nom = tiny
    block, _, _ = _joint_block([EFFECTS["casing_load"], EFFECTS["offset_drift"]], truth, R_nom, 5)
    w, phi, R, t = _samples(5, len(truth.leg_names), N=3)
    change, key = BAD[case]
    with pytest.raises(ValueError, match=rf"^my\.json: .*{re.escape(key)}"):
        correct_for_effect(_with(truth, _bad(block, change)), w, phi, R, t, source="my.json")
