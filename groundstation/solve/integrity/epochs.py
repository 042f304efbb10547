"""Positions at every epoch from the arcs' constants, with what the constants leave uncertain.

What this module owns: each epoch's least-squares position from its code and phase given the
arcs' constants and their covariance (:mod:`.lattice`), the covariance of that position, its
residual test, and how many of its satellites rest on a fixed constant.

The phase of a satellite whose constant is uncertain is weighted by that uncertainty: its
measurement covariance is the phase noise plus ``lambda^2 Q`` of the constants of the epoch's
arcs (generalised least squares with a full covariance). A fixed constant adds nothing and its
phase weighs in at millimetres; a float one adds its variance and weighs in little; a shift
common to all the epoch's constants is taken by the clock and moves nothing. So the one
formula gives a fixed, partly fixed or float position and an honest covariance for each.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from groundstation.solve.integrity.lattice import Lattice
from groundstation.solve.integrity.normal import CODE_FLOOR_M, LAM, PHASE_FLOOR_M
from groundstation.solve.integrity.table import PhaseTable

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

FIXED_SLOT_SIGMA_CYC = 0.01
"""A satellite's constant counts as fixed at an epoch when its standard deviation relative to
the epoch's other constants (the common part taken out) is below this."""
MIN_FIXED_SATS = 6
"""Satellites with a fixed constant an epoch needs to be fixed: 3 coordinates and a clock leave
2 degrees of freedom, enough to see one wrong constant."""
CHI2_LEVEL = 1e-3
"""False-alarm probability of an epoch's residual test."""


@dataclass(frozen=True, slots=True)
class EpochSolution:
    """Positions per epoch.

    Attributes:
        x: (n_ep, 3) ECEF (NaN where the epoch has too little code).
        cov: (n_ep, 3, 3) covariance, the constants' uncertainty included.
        chi2_dof: residual chi-square per degree of freedom (NaN without redundancy).
        chi2_ok: the residual test passes at :data:`CHI2_LEVEL`.
        n_fixed: satellites whose constant is fixed (:data:`FIXED_SLOT_SIGMA_CYC`).
        n_phase: satellites with a phase.
        fixed: fixed epoch: :data:`MIN_FIXED_SATS` fixed satellites and the test passed.
        residual_cyc: (n_ep, n_sv) phase residuals [cycles] (NaN where no phase was used).
        slot_fixed: (n_ep, n_sv) the satellite's constant counts as fixed there.
    """

    x: FloatArray
    cov: FloatArray
    chi2_dof: FloatArray
    chi2_ok: BoolArray
    n_fixed: IntArray
    n_phase: IntArray
    fixed: BoolArray
    residual_cyc: FloatArray
    slot_fixed: BoolArray


def solve_epochs(
    tab: PhaseTable, x0: FloatArray, lat: Lattice, code_inflation: float = 1.0,
    phase_factor: float = 1.0, iterations: int = 1,
) -> EpochSolution:
    """Each epoch's position given the constants (see the module doc), iterated from ``x0``."""
    from scipy import special  # chi-square tails; loaded when a solve gets here

    n_ep, n_sv = tab.sd_cyc.shape
    arc = tab.arc
    has_a = (arc >= 0) & np.isfinite(lat.constants[np.maximum(arc, 0)])
    a_slot = np.where(has_a, lat.constants[np.maximum(arc, 0)], 0.0)
    ia = np.maximum(arc, 0)
    q_slots = lat.cov[ia[:, :, None], ia[:, None, :]] * (LAM * LAM)
    sp = np.maximum(tab.sigma_cyc * LAM, PHASE_FLOOR_M) * np.sqrt(phase_factor)
    sc = np.maximum(tab.sigma_code_m, CODE_FLOOR_M) * np.sqrt(code_inflation)
    x = np.array(x0, dtype=np.float64, copy=True)
    good_start = np.all(np.isfinite(x), axis=1)
    x[~good_start] = 0.0
    eye = np.eye(n_sv)
    for it in range(iterations + 1):
        res_p, los = tab.residuals(x)
        res_c = tab.code_residuals(x)
        use_p = has_a & np.isfinite(res_p)
        use_c = np.isfinite(res_c) & np.all(np.isfinite(los), axis=2)
        h = np.concatenate([-np.nan_to_num(los), np.ones((n_ep, n_sv, 1))], axis=2)
        both = use_p[:, :, None] & use_p[:, None, :]
        cp = np.where(both, q_slots, 0.0) + eye[None] * np.where(use_p, sp * sp, 1.0)[:, :, None]
        wp = np.linalg.inv(cp)
        wp = np.where(both, wp, 0.0)
        hp = np.where(use_p[:, :, None], h, 0.0)
        yp = np.where(use_p, (res_p - a_slot) * LAM, 0.0)
        wc = np.where(use_c, 1.0 / (sc * sc), 0.0)
        yc = np.where(use_c, res_c, 0.0)
        normal = (np.einsum("esi,est,etj->eij", hp, wp, hp)
                  + np.einsum("esi,esj,es->eij", h, h, wc))
        rhs = np.einsum("esi,est,et->ei", hp, wp, yp) + np.einsum("esi,es->ei", h, wc * yc)
        ok = good_start & (np.sum(use_c, axis=1) >= 5)
        normal[~ok] = np.eye(4)
        rhs[~ok] = 0.0
        cov4 = np.linalg.inv(normal)
        d = np.einsum("eij,ej->ei", cov4, rhs)
        if it == iterations:
            break
        x = x + np.where(ok[:, None], d[:, :3], 0.0)
    # residuals after the last step (the linearisation point is the current x)
    vp = yp - np.einsum("esi,ei->es", hp, d)
    vc = yc - np.einsum("esi,ei->es", h, d)
    x = x + np.where(ok[:, None], d[:, :3], 0.0)
    chi = np.einsum("es,est,et->e", vp, wp, vp) + np.sum(wc * vc * vc, axis=1)
    dof = np.sum(use_p, axis=1) + np.sum(use_c, axis=1) - 4
    chi_dof = np.where(dof > 0, chi / np.maximum(dof, 1), np.nan)
    limit = special.chdtri(np.maximum(dof, 1), CHI2_LEVEL) / np.maximum(dof, 1)
    chi_ok = (dof > 0) & (chi_dof <= limit)
    # satellites on a fixed constant: small variance once the epoch's common part is removed
    m = np.maximum(np.sum(use_p, axis=1), 1)
    qv = np.where(both, q_slots, 0.0) / (LAM * LAM)
    row_mean = qv.sum(axis=2) / m[:, None]
    all_mean = qv.sum(axis=(1, 2)) / (m * m)
    proj_var = np.einsum("eii->ei", qv) - 2 * row_mean + all_mean[:, None]
    slot_fixed = use_p & (proj_var < FIXED_SLOT_SIGMA_CYC**2)
    n_fixed = np.sum(slot_fixed, axis=1)
    x[~ok] = np.nan
    fixed = ok & chi_ok & (n_fixed >= MIN_FIXED_SATS)
    resid = np.where(use_p & ok[:, None], vp / LAM, np.nan)
    return EpochSolution(x, cov4[:, :3, :3], chi_dof, chi_ok, n_fixed,
                         np.sum(use_p, axis=1), fixed, resid, slot_fixed)
