"""Forward and backward solutions merged (solve/engine/combine.py): demo5's combres with a
full-covariance check of each fix of both runs."""

from __future__ import annotations

import numpy as np
import pytest

from groundstation.solve.engine import combine as cb
from groundstation.solve.posfile import parse_pos

HEAD = [
    "% program   : groundstation demo5",
    "% solution  : Forward",
    ("%  GPST                         x-ecef(m)      y-ecef(m)      z-ecef(m)   Q  ns   sdx(m)"
     "   sdy(m)   sdz(m)  sdxy(m)  sdyz(m)  sdzx(m) age(s)  ratio"),
]
X0 = np.array([3774696.5, -596647.9, 5089485.6])


def line(sec: int, dx: tuple[float, float, float], q: int, sd: float = 0.01,
         sdxy: float = 0.0, ns: int = 9, ratio: float = 20.0) -> str:
    x = X0 + np.asarray(dx)
    return (f"2018/10/09 12:22:{sec:09.6f} {x[0]:14.4f} {x[1]:14.4f} {x[2]:14.4f} {q:3d} {ns:3d} "
            f"{sd:8.4f} {sd:8.4f} {sd:8.4f} {sdxy:8.4f} {0.0:8.4f} {0.0:8.4f} {1.0:6.2f} "
            f"{ratio:6.1f}")


def text(lines: list[str], backward: bool = False) -> str:
    head = [h.replace("Forward", "Backward") if backward else h for h in HEAD]
    # RTKLIB writes a backward solution in reverse time order.
    return "\n".join(head + (lines[::-1] if backward else lines)) + "\n"


def merged(fwd: list[str], bwd: list[str]) -> tuple[str, cb.CombineStats]:
    return cb.combine_text(text(fwd), text(bwd, backward=True))


def test_consistent_fixes_are_averaged_and_stay_fixed() -> None:
    out, stats = merged([line(10, (0.0, 0.0, 0.0), 1)], [line(10, (0.01, 0.0, 0.0), 1)])
    traj = parse_pos(out, source="t")
    assert traj.quality.tolist() == [1]
    # Equal covariances: the mean, and the variance halves.
    assert traj.ecef_m[0, 0] == pytest.approx(X0[0] + 0.005, abs=1e-4)
    assert "% solution  : Combined (forward and backward combined by groundstation)" in out
    assert stats.both_fixed == 1 and stats.demo5_rejected == 0 and stats.chi2_rejected == 0
    sd = float(out.strip().splitlines()[-1].split()[7])
    assert sd == pytest.approx(0.01 / np.sqrt(2), abs=1e-4)


def test_a_disagreement_demo5_lets_through_is_not_a_fix() -> None:
    # 4.5 cm on X and Y with 1 cm sigma per run: each axis is within demo5's 4 sigma
    # (4 * sqrt(2) cm = 5.7 cm) but the 3-D difference is chi-square 20 (> 11.3 at 1 %).
    d = (0.045, 0.045, 0.0)
    out, stats = merged([line(10, (0, 0, 0), 1)], [line(10, d, 1)])
    assert parse_pos(out, source="t").quality.tolist() == [2]
    assert stats.demo5_rejected == 0 and stats.chi2_rejected == 1
    demo5_ok, chi2_ok = cb.consistent(np.array(d), np.eye(3) * 2e-4)
    assert demo5_ok and not chi2_ok
    # The same 4.5 cm along one axis only is chi-square 10: consistent, fixed.
    out, stats = merged([line(10, (0, 0, 0), 1)], [line(10, (0.045, 0, 0), 1)])
    assert parse_pos(out, source="t").quality.tolist() == [1] and stats.chi2_rejected == 0
    # Beyond 4 sigma on one axis: demo5's own test.
    out, stats = merged([line(10, (0, 0, 0), 1)], [line(10, (0.06, 0, 0), 1)])
    assert parse_pos(out, source="t").quality.tolist() == [2] and stats.demo5_rejected == 1


def test_the_correlations_count() -> None:
    """X and Y strongly correlated (sdxy 0.0095 m with sd 0.01 m): a difference across the
    correlation is far less likely than its per-axis size says."""
    f = [line(10, (0, 0, 0), 1, sdxy=0.0095)]
    along = merged(f, [line(10, (0.03, 0.03, 0), 1, sdxy=0.0095)])
    across = merged(f, [line(10, (0.03, -0.03, 0), 1, sdxy=0.0095)])
    assert parse_pos(along[0], source="t").quality.tolist() == [1]
    assert parse_pos(across[0], source="t").quality.tolist() == [2]
    assert across[1].chi2_rejected == 1 and across[1].demo5_rejected == 0


def test_better_quality_is_taken_whole_and_lone_epochs_kept() -> None:
    fwd = [line(10, (0, 0, 0), 2, sd=0.3, ratio=1.5), line(11, (0, 0, 0), 1),
           line(12, (1, 0, 0), 5)]
    bwd = [line(10, (0.2, 0, 0), 1, ns=11), line(11, (0.5, 0, 0), 2, sd=0.3),
           line(13, (0, 0, 0), 1)]
    out, stats = merged(fwd, bwd)
    rows = [ln for ln in out.splitlines() if not ln.startswith("%")]
    assert rows == [bwd[0], fwd[1], fwd[2], bwd[2]]
    assert stats.epochs == 4 and stats.one_run_only == 2 and stats.both_fixed == 0


def test_velocity_columns_are_refused() -> None:
    with_vel = line(10, (0, 0, 0), 1) + "   0.0010   0.0020   0.0030"
    with pytest.raises(ValueError, match="xyz solution line without velocity"):
        merged([with_vel], [line(10, (0, 0, 0), 1)])
