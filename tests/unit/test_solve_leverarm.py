"""Lever arm with ω φ κ: DOMAIN.md §7 worked example, opposite heading, round trip, EO files."""

from __future__ import annotations

import numpy as np
import pytest

from groundstation.errors import InputError
from groundstation.solve import leverarm

LEVER = (0.16, -0.03, 0.57)
ANTENNA = np.array([[712767.733, 6181293.545, 36.599]])


def test_worked_example_to_a_tenth_of_a_millimetre() -> None:
    opk = np.array([[2.0, -1.5, 165.0]])
    off = leverarm.lever_offsets(opk, LEVER)[0]
    assert off == pytest.approx([-0.1617, 0.0506, 0.5681], abs=1e-4)
    cam = leverarm.apply_lever_arm(ANTENNA, opk, LEVER)[0]
    assert cam == pytest.approx([712767.8947, 6181293.4944, 36.0309], abs=1e-4)


def test_opposite_flight_direction_flips_the_horizontal_correction() -> None:
    off = leverarm.lever_offsets(np.array([[2.0, -1.5, -15.0]]), LEVER)[0]
    assert off == pytest.approx([0.1318, -0.0904, 0.5708], abs=1e-4)
    fwd = leverarm.lever_offsets(np.array([[2.0, -1.5, 165.0]]), LEVER)[0]
    assert np.sign(off[:2]).tolist() == (-np.sign(fwd[:2])).tolist()


def test_matrix_is_r_kappa_r_phi_r_omega() -> None:
    o, p, k = np.radians([2.0, -1.5, 165.0])
    r_o = np.array([[1, 0, 0], [0, np.cos(o), np.sin(o)], [0, -np.sin(o), np.cos(o)]])
    r_p = np.array([[np.cos(p), 0, -np.sin(p)], [0, 1, 0], [np.sin(p), 0, np.cos(p)]])
    r_k = np.array([[np.cos(k), np.sin(k), 0], [-np.sin(k), np.cos(k), 0], [0, 0, 1]])
    assert leverarm.rotation_matrix(2.0, -1.5, 165.0) == pytest.approx(r_k @ r_p @ r_o)


def test_estimate_round_trip_with_an_outlier() -> None:
    rng = np.random.default_rng(3)
    n = 50
    opk = np.column_stack([rng.normal(0, 2, n), rng.normal(0, 2, n), rng.uniform(-180, 180, n)])
    ant = ANTENNA + rng.normal(0, 50, (n, 3))
    cam = leverarm.apply_lever_arm(ant, opk, LEVER) + rng.normal(0, 0.003, (n, 3))
    cam[7] += (0.5, 0.0, 0.0)  # a badly oriented image
    est = leverarm.estimate_lever_arm(ant, cam, opk)
    assert est.outlier.tolist().count(True) == 1 and est.outlier[7]
    assert est.mean_m == pytest.approx(LEVER, abs=0.002)
    assert np.all(est.sigma_m < 0.005)


def test_estimate_needs_two_images() -> None:
    with pytest.raises(InputError):
        leverarm.estimate_lever_arm(ANTENNA, ANTENNA, np.zeros((1, 3)))


def test_kappa_from_track() -> None:
    e = np.array([0.0, 1.0, 2.0, 2.0, 2.0])
    n = np.array([0.0, 0.0, 0.0, -1.0, -2.0])
    k = leverarm.kappa_from_track_deg(e, n)
    assert k[0] == pytest.approx(0.0)  # flying east
    assert k[-1] == pytest.approx(-90.0)  # flying south
    assert abs(leverarm.kappa_from_track_deg(-e, n)[0]) == pytest.approx(180.0)  # west


def test_parse_eo_formats() -> None:
    text = (
        "# exported\nname,X,Y,Z,omega,phi,kappa\n"
        "IMG_0001.JPG,712767.8947,6181293.4944,36.0309,2,-1.5,165\n"
    )
    eo = leverarm.parse_eo(text)
    assert eo[0].name == "IMG_0001.JPG" and eo[0].kappa_deg == 165.0
    eo2 = leverarm.parse_eo("IMG_2 1 2 3 0.1 0.2 0.3\nIMG_3\t1\t2\t3\t0\t0\t0\n")
    assert [e.name for e in eo2] == ["IMG_2", "IMG_3"]
    with pytest.raises(InputError):
        leverarm.parse_eo("IMG_1,1,2,3\n")
    with pytest.raises(InputError):
        leverarm.parse_eo("IMG_1,1,2,3,0,0,0\nIMG_2,1,x,3,0,0,0\n")
