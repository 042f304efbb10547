"""Photo matching on real JPEG files with real EXIF: offsets of hours, bursts, lost/extra marks."""

from __future__ import annotations

import datetime as dt
from pathlib import Path

import numpy as np
import pytest

from groundstation.errors import InputError
from groundstation.solve import photos
from groundstation.solve.photosim import PhotoScenario, photo_scenario, write_photo_set


def _score(sc: PhotoScenario, res: photos.MatchResult) -> tuple[int, int]:
    got = [-1] * len(sc.photos)
    for p in res.pairs:
        got[p.photo] = p.mark
    correct = sum(g == t for g, t in zip(got, sc.truth, strict=True))
    return correct, len(sc.photos)


def _run(sc: PhotoScenario, d: Path) -> photos.MatchResult:
    write_photo_set(sc, d)
    ph = photos.scan_photos(d)
    assert [p.name for p in ph] == [p.name for p in sc.photos]
    return photos.match(photos.photo_times(ph), list(sc.mark_t_gps_ns))


CASES = {
    # name: scenario options
    "subsec, hours+minutes offset, no zone tag": {"subsec": True},
    "subsec, zone tag +02:00, offset -5h41m": {
        "subsec": True, "write_zone": True, "clock_error_s": -(5 * 3600 + 41 * 60 + 7.46)},
    "whole seconds, offset +3h12m": {
        "subsec": False, "clock_error_s": 3 * 3600 + 12 * 60 + 51.8, "extra_min_sep_s": 1.2},
    "whole seconds, zone tag, offset -2h17m": {
        "subsec": False, "write_zone": True, "extra_min_sep_s": 1.2},
}


@pytest.mark.parametrize("name", list(CASES))
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_all_pairs_correct(tmp_path: Path, name: str, seed: int) -> None:
    sc = photo_scenario(300, seed=seed, **CASES[name])  # type: ignore[arg-type]
    res = _run(sc, tmp_path)
    correct, n = _score(sc, res)
    lost = sc.truth.count(-1)
    print(f"{name} seed {seed}: {correct}/{n} photos correct, {len(res.pairs)} pairs, "
          f"{lost} marks lost, {len(sc.extra_marks)} extra marks, offset {res.offset_s:+.2f} s")
    assert correct == n
    assert len(res.unmatched_photos) == lost == 15
    assert set(res.orphan_marks) == set(sc.extra_marks) and len(sc.extra_marks) == 15
    bursts = sum(
        1 for a, b in zip(sc.photos, sc.photos[3:], strict=False)
        if b.true_t_gps_ns - a.true_t_gps_ns < 1_000_000_000
    )
    assert bursts > 5  # the scenario really has bursts of 4 per second


def test_offset_is_recovered_to_a_hundredth(tmp_path: Path) -> None:
    err = -(2 * 3600 + 17 * 60 + 23.37)
    sc = photo_scenario(200, subsec=True, clock_error_s=err, zone_s=7200, write_zone=True)
    res = _run(sc, tmp_path)
    # Camera clock = UTC + zone + err and the zone tag is honoured: GPS - camera = -err.
    assert res.offset_s == pytest.approx(-err, abs=0.011)


def test_large_set_1000_photos(tmp_path: Path) -> None:
    sc = photo_scenario(1000, seed=7, subsec=True)
    res = _run(sc, tmp_path)
    assert _score(sc, res) == (1000, 1000)


def test_duplicate_marks_dropped_and_reported() -> None:
    sc = photo_scenario(50, seed=3, subsec=True, missing_fraction=0.0, extra_fraction=0.0)
    ph = [
        photos.Photo(p.name, "", int(p.exif_datetime.replace(tzinfo=dt.UTC).timestamp()) * 10**9,
                     int(p.subsec or "0") * 10_000_000)
        for p in sc.photos
    ]
    marks: list[int | None] = [*sc.mark_t_gps_ns, sc.mark_t_gps_ns[10], None]
    res = photos.match(photos.photo_times(ph), marks)
    assert res.duplicate_marks == (50,)
    assert len(res.pairs) == 50 and res.orphan_marks == ()
    lines = photos.reconciliation_lines(res, ph, marks)
    assert "1 duplicate marks dropped" in lines[2]


def test_burst_spread_by_file_order() -> None:
    second = 1_700_000_000 * 10**9
    ph = [photos.Photo(f"IMG_{i}.JPG", "", second) for i in range(4)]
    ph.append(photos.Photo("IMG_9.JPG", "", second + 10**9))
    t = photos.photo_times(ph)
    frac = t.t_s - np.floor(t.t_s)
    assert frac[:4] == pytest.approx([0.10, 0.35, 0.65, 0.90], abs=1e-6)
    assert frac[4] == pytest.approx(0.5, abs=1e-6)
    assert not t.precise.any()


def test_read_photo_exif_fields(tmp_path: Path) -> None:
    p = tmp_path / "a.jpg"
    p.write_bytes(photos.make_jpeg(dt.datetime(2018, 10, 9, 14, 22, 5), subsec="37",
                                   offset_time="+02:00"))
    ph = photos.read_photo(p)
    assert ph.usable and ph.subsec_ns == 370_000_000 and ph.utc_offset_s == 7200
    assert ph.utc_second_ns == int(dt.datetime(2018, 10, 9, 12, 22, 5,
                                               tzinfo=dt.UTC).timestamp()) * 10**9
    (tmp_path / "b.jpg").write_bytes(photos.make_jpeg(None))
    (tmp_path / "c.jpg").write_bytes(b"not a jpeg")
    got = {x.name: x for x in photos.scan_photos(tmp_path)}
    assert got["b.jpg"].error and got["c.jpg"].error and not got["c.jpg"].usable


def test_jpeg_is_a_real_baseline_jpeg() -> None:
    data = photos.make_jpeg(dt.datetime(2020, 1, 1))
    assert data[:2] == b"\xff\xd8" and data[-2:] == b"\xff\xd9"
    assert b"\xff\xc0" in data and b"Exif\x00\x00" in data


def test_gps_copy_leaves_the_original_alone(tmp_path: Path) -> None:
    src = tmp_path / "IMG_1.JPG"
    src.write_bytes(photos.make_jpeg(dt.datetime(2020, 1, 1)))
    before = src.read_bytes()
    dst = tmp_path / "out" / "IMG_1.JPG"
    dst.parent.mkdir()
    photos.write_gps_copy(src, dst, 53.28044996, -9.05783633, 66.8)
    assert src.read_bytes() == before
    from exif import Image

    img = Image(dst.read_bytes())
    d, m, s = img.gps_latitude
    assert d + m / 60 + s / 3600 == pytest.approx(53.28044996, abs=1e-7)
    assert img.gps_longitude_ref == "W" and img.gps_altitude == pytest.approx(66.8)
    with pytest.raises(InputError):
        photos.write_gps_copy(src, src, 0.0, 0.0, 0.0)


def test_scan_requires_a_directory(tmp_path: Path) -> None:
    with pytest.raises(InputError):
        photos.scan_photos(tmp_path / "missing")


def test_natural_order() -> None:
    names = ["IMG_10.JPG", "IMG_9.JPG", "img_100.jpg"]
    assert sorted(names, key=photos.natural_key) == ["IMG_9.JPG", "IMG_10.JPG", "img_100.jpg"]


@pytest.mark.parametrize("subsec", [False, True])
def test_residual_sigma_is_that_of_the_pairs(tmp_path: Path, subsec: bool) -> None:
    """One residual σ: the robust σ of the final pairs' residuals, whatever the photos' timing.

    Whole-second photos used to report the pairing cap (0.750 s) as their σ while the report
    computed the pairs' own spread (a few ms)."""
    sc = photo_scenario(120, seed=5, subsec=subsec, missing_fraction=0.0, extra_fraction=0.0)
    res = _run(sc, tmp_path)
    r = np.array([p.residual_s for p in res.pairs])
    assert res.residual_sigma_s == pytest.approx(photos.residual_sigma_s(r), abs=1e-12)
    assert res.residual_sigma_s == pytest.approx(
        1.4826 * float(np.median(np.abs(r - np.median(r)))), abs=1e-12)
    assert res.residual_sigma_s < photos.MAX_PAIR_S / 2
    line = photos.reconciliation_lines(res, photos.scan_photos(tmp_path), sc.mark_t_gps_ns)[1]
    assert f"timing residual sigma {res.residual_sigma_s * 1e3:.1f} ms (robust)" in line


def test_residual_sigma_needs_three_pairs() -> None:
    assert np.isnan(photos.residual_sigma_s(np.array([0.1, 0.2])))
    assert photos.residual_sigma_text(float("nan")) == "not computed (fewer than 3 pairs)"
