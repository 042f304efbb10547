"""Positions at marks: linear, spline, smoother on synthetic trajectories; gaps; quality; edges."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest

from groundstation.errors import ConfigError, InputError
from groundstation.geodesy import enu_rotation, llh_to_ecef
from groundstation.solve import interpolate as ip
from groundstation.solve.integrity import grade as gr
from groundstation.solve.trajectory import Trajectory, make_trajectory

T0 = 2022 * 604_800 * 10**9 + 217_000 * 10**9
LAT, LON = 53.28, -9.06
ORIGIN = np.array(llh_to_ecef(LAT, LON, 60.0))
ROT = np.array(enu_rotation(LAT, LON))


def truth_enu(t_s: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """A smooth flight: ~2-3 m/s with turns and a gentle climb."""
    return np.column_stack(
        [20 * np.sin(0.1 * t_s), 15 * np.sin(0.07 * t_s + 1), 30 + 2 * np.sin(0.05 * t_s)]
    )


def traj_from_enu(
    t_s: npt.NDArray[np.float64], enu: npt.NDArray[np.float64], sd: tuple[float, float, float],
    quality: npt.NDArray[np.int64] | None = None,
) -> Trajectory:
    n = t_s.size
    return make_trajectory(
        T0 + np.round(t_s * 1e9).astype(np.int64), ORIGIN + enu @ ROT,
        np.ones(n, np.int64) if quality is None else quality,
        sd_enu_m=np.tile(sd, (n, 1)),
    )


def to_enu(ecef: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    return np.asarray((ecef - ORIGIN) @ ROT.T)


def rms(e: npt.NDArray[np.float64]) -> float:
    return float(np.sqrt(np.mean(np.sum(e**2, axis=1))))


def test_smoother_beats_linear_on_a_noisy_5hz_trajectory() -> None:
    rng = np.random.default_rng(1)
    t_ep = np.arange(0.0, 600.0, 0.2)
    sd = (0.01, 0.01, 0.02)
    traj = traj_from_enu(t_ep, truth_enu(t_ep) + rng.normal(0, 1, (t_ep.size, 3)) * sd, sd)
    t_mk = np.sort(rng.uniform(1.0, 599.0, 500))
    times: list[int | None] = [T0 + round(x * 1e9) for x in t_mk]
    truth = truth_enu(t_mk)
    got = {m: rms(to_enu(ip.interpolate(traj, times, m).ecef_m) - truth)
           for m in ("linear", "spline", "smoother")}
    print("RMS at marks (m):", {k: round(v, 4) for k, v in got.items()})
    assert got["smoother"] < 0.8 * got["linear"]
    assert got["linear"] < 0.03


def test_noise_free_spline_is_closer_than_linear_on_a_curve() -> None:
    t_ep = np.arange(0.0, 120.0, 0.2)
    traj = traj_from_enu(t_ep, truth_enu(t_ep), (0.01, 0.01, 0.01))
    t_mk = np.arange(1.1, 119.0, 0.73)
    times: list[int | None] = [T0 + round(x * 1e9) for x in t_mk]
    lin = rms(to_enu(ip.interpolate_linear(traj, times).ecef_m) - truth_enu(t_mk))
    spl = rms(to_enu(ip.interpolate_spline(traj, times).ecef_m) - truth_enu(t_mk))
    assert spl < lin / 10
    assert spl < 1e-4


def test_linear_exact_on_epochs_and_between() -> None:
    t_ep = np.array([0.0, 1.0, 2.0])
    enu = np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 3.0], [3.0, 2.0, 1.0]])
    traj = traj_from_enu(t_ep, enu, (0.01, 0.01, 0.01))
    times: list[int | None] = [T0, T0 + 500_000_000, T0 + 2 * 10**9, T0 + 1_250_000_000]
    got = to_enu(ip.interpolate_linear(traj, times).ecef_m)
    assert got == pytest.approx(
        np.array([[0, 0, 0], [0.5, 1.0, 1.5], [3, 2, 1], [1.5, 2.0, 2.5]]), abs=1e-6
    )


def test_several_marks_in_one_epoch_for_every_method() -> None:
    t_ep = np.arange(0.0, 10.0, 0.2)
    traj = traj_from_enu(t_ep, truth_enu(t_ep), (0.01, 0.01, 0.02))
    # Three marks inside the same 0.2 s epoch, one of them twice (duplicate), unsorted.
    base = T0 + 5 * 10**9
    times: list[int | None] = [base + 150_000_000, base + 20_000_000, base + 90_000_000,
                               base + 20_000_000]
    for method in ip.INTERPOLATORS:
        mp = ip.interpolate(traj, times, method)
        assert mp.positioned == 4
        e = to_enu(mp.ecef_m) - truth_enu((np.array([t for t in times if t]) - T0) / 1e9)
        assert np.max(np.abs(e)) < 0.05, method
        assert mp.flags[3] & ip.FLAG_DUPLICATE and not mp.flags[1] & ip.FLAG_DUPLICATE
        assert len(set(mp.ecef_m[:3, 0].tolist())) == 3


def test_gap_is_flagged_never_silently_bridged() -> None:
    t_ep = np.concatenate([np.arange(0.0, 10.0, 0.2), np.arange(13.0, 20.0, 0.2)])
    traj = traj_from_enu(t_ep, truth_enu(t_ep), (0.01, 0.01, 0.02))
    times: list[int | None] = [T0 + 5 * 10**9, T0 + 11 * 10**9, T0 + 15 * 10**9]
    for method in ip.INTERPOLATORS:
        mp = ip.interpolate(traj, times, method, max_gap_s=1.0)
        assert [bool(f & ip.FLAG_GAP) for f in mp.flags] == [False, True, False], method
        assert mp.bracket_s[1] == pytest.approx(3.2)
    # With a longer max_gap the same mark is not in a gap.
    assert not ip.interpolate(traj, times, "linear", max_gap_s=5.0).flags[1] & ip.FLAG_GAP


def test_quality_is_the_worse_bracketing_epoch_and_outside_has_none() -> None:
    t_ep = np.arange(0.0, 2.0, 0.2)
    q = np.array([1, 1, 2, 1, 1, 5, 1, 1, 1, 1], np.int64)
    traj = traj_from_enu(t_ep, truth_enu(t_ep), (0.01, 0.01, 0.02), q)
    times: list[int | None] = [
        T0 + 100_000_000,  # between 1 and 1
        T0 + 300_000_000,  # between 1 and 2
        T0 + 900_000_000,  # between 1 and 5
        T0 + 400_000_000,  # exactly on the float epoch
        T0 + 600_000_000,  # exactly on a fixed epoch next to the float one
        T0 - 10**9,  # before the first epoch
        None,  # no edge
    ]
    mp = ip.interpolate_linear(traj, times)
    assert mp.quality.tolist() == [1, 2, 5, 2, 1, 0, 0]
    assert mp.flags[5] & ip.FLAG_OUTSIDE and np.isnan(mp.ecef_m[5, 0])
    assert mp.flags[6] & ip.FLAG_NO_EDGE and np.isnan(mp.ecef_m[6, 0])
    assert mp.flags[1] & ip.FLAG_NOT_FIXED and not mp.flags[0] & ip.FLAG_NOT_FIXED


def test_smoother_sigma_is_never_tighter_than_the_epochs() -> None:
    """The smoother takes each epoch's error as independent of the next one's; a fixed
    solution's multipath and a float one's errors last for seconds to tens of seconds, so its
    averaging down (to a few millimetres here) is not taken: a mark is as sure as its epochs."""
    rng = np.random.default_rng(2)
    t_ep = np.arange(0.0, 60.0, 0.2)
    sd = (0.02, 0.02, 0.04)
    traj = traj_from_enu(t_ep, truth_enu(t_ep) + rng.normal(0, 1, (t_ep.size, 3)) * sd, sd)
    mp = ip.interpolate_smoother(traj, [T0 + 30_100_000_000])
    assert mp.sd_enu_m[0].tolist() == pytest.approx(list(sd))


def test_the_smoother_bridges_a_radio_gap_between_fixes_and_leaves_floats_straight() -> None:
    """A 1.4 s radio gap in a fixed 5 Hz flight: the straight line's sigma (``a w (1 - w) h^2
    / 2``, the acceleration not measurable across the gap, so the flight's largest) takes the
    mark in its middle out of the centimetre class, the smoother keeps it there with a sigma
    that covers its error (measured on this flight: 0.8 s 1.2 cm, 1.4 s 3.1 cm, 1.6 s 4.0 cm).
    Between float epochs the smoother gives the straight line and its sigma (its averaging
    would make a float's sigma lie)."""
    rng = np.random.default_rng(3)
    t_ep = np.round(np.concatenate([np.arange(0.0, 30.0, 0.2), np.arange(31.2, 60.0, 0.2)]), 3)
    sd = (0.005, 0.005, 0.01)
    enu = truth_enu(t_ep) + rng.normal(0, 1, (t_ep.size, 3)) * sd
    mark = [T0 + 30_500_000_000]
    fixed = dataclasses.replace(traj_from_enu(t_ep, enu, sd),
                                grade=np.full(t_ep.size, gr.FIXED, np.int64))  # checked
    lin, smo = ip.interpolate_linear(fixed, mark), ip.interpolate_smoother(fixed, mark)
    assert lin.flags[0] & ip.FLAG_NOT_FIXED and lin.quality[0] == 2
    assert float(np.max(lin.sd_enu_m[0])) > 0.033 and lin.grade[0] == gr.FLOAT
    assert smo.quality[0] == 1 and float(np.max(smo.sd_enu_m[0])) <= 0.033
    assert smo.grade[0] == gr.FIXED
    err = np.abs(to_enu(smo.ecef_m)[0] - truth_enu(np.array([30.5]))[0])
    assert np.all(err <= 3 * smo.sd_enu_m[0]), (err, smo.sd_enu_m[0])
    floats = traj_from_enu(t_ep, enu, (0.3, 0.3, 0.5), np.full(t_ep.size, 2, np.int64))
    a, b = ip.interpolate_linear(floats, mark), ip.interpolate_smoother(floats, mark)
    assert np.array_equal(a.ecef_m, b.ecef_m) and np.array_equal(a.sd_enu_m, b.sd_enu_m)


def test_edge_choice_and_shutter_delay() -> None:
    f, r = 1_000_000_000, 1_014_160_000
    assert ip.mark_time_ns(f, r, "falling") == f
    assert ip.mark_time_ns(f, r, "rising") == r
    assert ip.mark_time_ns(f, r, "mid") == (f + r) // 2
    assert ip.mark_time_ns(f, r, "falling", 12.5) == f + 12_500_000
    assert ip.mark_time_ns(f, None, "mid") is None
    assert ip.mark_time_ns(None, r, "falling") is None


def test_unknown_method_is_a_config_error() -> None:
    traj = traj_from_enu(np.arange(3.0), np.zeros((3, 3)), (0.01, 0.01, 0.01))
    with pytest.raises(ConfigError) as err:
        ip.interpolate(traj, [T0], "cubic")
    assert err.value.key == "--interp"
    with pytest.raises(ConfigError):
        ip.interpolate(traj, [T0], "linear", max_gap_s=0.0)


def test_natural_spline_second_derivatives_vanish_at_the_ends() -> None:
    x = np.linspace(0.0, 5.0, 11)
    y = np.column_stack([np.sin(x), x**2])
    m2 = ip.natural_spline_m2(x, y)
    assert m2[0].tolist() == [0.0, 0.0] and m2[-1].tolist() == [0.0, 0.0]
    assert m2[5, 1] == pytest.approx(2.0, abs=0.1)


def test_every_method_and_every_check_has_words_for_the_printout() -> None:
    from groundstation.solve.integrity.grade import CHECK_NAMES, CHECK_TEXT
    from groundstation.solve.interpolate import INTERPOLATORS, METHOD_TEXT

    assert set(METHOD_TEXT) == set(INTERPOLATORS)
    assert set(CHECK_TEXT) == {c for c in CHECK_NAMES if c}


@pytest.mark.parametrize("method", sorted(ip.INTERPOLATORS))
def test_every_method_moves_with_the_trajectory(method: str) -> None:
    """What a re-base rests on (``solve --rebase`` takes the finished result's positions at
    the marks moved with the base instead of interpolating again): the trajectory moved by a
    vector gives the positions moved by that vector, the same sigmas, flags and grades."""
    rng = np.random.default_rng(5)
    t_ep = np.round(np.concatenate([np.arange(0.0, 20.0, 0.2), np.arange(21.4, 40.0, 0.2)]), 3)
    sd = (0.005, 0.005, 0.01)
    traj = dataclasses.replace(
        traj_from_enu(t_ep, truth_enu(t_ep) + rng.normal(0, 1, (t_ep.size, 3)) * sd, sd),
        grade=np.full(t_ep.size, gr.FIXED, np.int64))
    marks = [T0 + round(t * 1e9) for t in (0.1, 5.55, 20.7, 33.333)] + [None]
    move = ROT.T @ np.array([0.8, -0.6, 1.2])  # a base moved 1.6 m
    a = ip.interpolate(traj, marks, method)
    b = ip.interpolate(dataclasses.replace(traj, ecef_m=traj.ecef_m + move), marks, method)
    ok = np.isfinite(a.ecef_m[:, 0])
    assert ok.sum() == 4 and np.array_equal(ok, np.isfinite(b.ecef_m[:, 0]))
    assert np.max(np.abs(b.ecef_m[ok] - a.ecef_m[ok] - move)) < 1e-6
    assert np.allclose(a.sd_enu_m[ok], b.sd_enu_m[ok], rtol=0, atol=1e-9)
    for k in ("quality", "flags", "grade", "check", "t_gps_ns"):
        assert np.array_equal(getattr(a, k), getattr(b, k)), k


def test_positions_written_and_read_back_are_the_same(tmp_path: Path) -> None:
    t_ep = np.arange(0.0, 10.0, 0.2)
    traj = traj_from_enu(t_ep, truth_enu(t_ep), (0.01, 0.01, 0.02))
    sets = [ip.interpolate(traj, [T0 + 3_100_000_000, None, T0 + 99 * 10**9], m)
            for m in ("smoother", "linear")]
    ip.save_npz(sets, tmp_path / "p.npz")
    back = ip.load_npz(tmp_path / "p.npz")
    assert len(back) == 2
    for a, b in zip(sets, back, strict=True):
        for f in dataclasses.fields(ip.MarkPositions):
            x, y = getattr(a, f.name), getattr(b, f.name)
            assert (x == y if isinstance(x, str) else np.array_equal(x, y, equal_nan=True)), f
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    with pytest.raises(InputError, match="not positions this program wrote"):
        ip.load_npz(tmp_path / "bad.npz")
