"""Photo matching on real JPEG files with real EXIF: offsets of hours, bursts, lost/extra marks."""

from __future__ import annotations

import datetime as dt
from pathlib import Path

import numpy as np
import pytest

from groundstation import gpstime
from groundstation.errors import InputError
from groundstation.solve import clockoffset, exif, photos
from groundstation.solve.photosim import PhotoScenario, photo_scenario, write_photo_set


def _score(sc: PhotoScenario, res: photos.MatchResult) -> tuple[int, int]:
    got = [-1] * len(sc.photos)
    for p in res.pairs:
        got[p.photo] = p.mark
    correct = sum(g == t for g, t in zip(got, sc.truth, strict=True))
    return correct, len(sc.photos)


def _run(sc: PhotoScenario, d: Path) -> photos.MatchResult:
    write_photo_set(sc, d)
    ph = exif.scan_photos(d)
    assert [p.name for p in ph] == [p.name for p in sc.photos]
    return photos.match(clockoffset.photo_times(ph), list(sc.mark_t_gps_ns))


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
    assert not res.warnings and not res.notes  # irregular marks: one pairing, nothing to say
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
    # Camera clock = UTC + zone + err and the zone tag is honoured: UTC - camera = -err.
    assert res.offset_s == pytest.approx(-err, abs=0.011)


def test_large_set_1000_photos(tmp_path: Path) -> None:
    sc = photo_scenario(1000, seed=7, subsec=True)
    res = _run(sc, tmp_path)
    assert _score(sc, res) == (1000, 1000)
    assert not res.warnings


# A camera on a timer: marks every 2.0 s, always 0.15 s into the UTC second (the real
# 2018-10-09 flight: 1.96-2.03 s apart, 0.13-0.17 s in). Marks 2018-10-09 12:20 GPS.
_T0_GPS_NS = gpstime.datetime_to_gps_ns(dt.datetime(2018, 10, 9, 12, 20, tzinfo=dt.UTC))


def _timer_marks(n: int, seed: int = 3) -> list[int | None]:
    rng = np.random.default_rng(seed)
    return [_T0_GPS_NS + k * 2_000_000_000 + 150_000_000 + int(rng.normal(0, 3e6))
            for k in range(n)]


def _photos_at(marks: list[int | None], clock_error_s: float) -> list[exif.Photo]:
    """Whole-second photos of the given marks, the camera clock ``clock_error_s`` ahead of UTC."""
    out = []
    for k, t in enumerate(marks):
        assert t is not None
        unix_ns = gpstime.gps_to_unix_ns(t) + int(clock_error_s * 1e9)
        second = unix_ns // gpstime.NS_PER_S * gpstime.NS_PER_S
        out.append(exif.Photo(f"IMG_{k:04d}.JPG", f"/x/IMG_{k:04d}.JPG", second))
    return out


@pytest.mark.parametrize(("first", "count"), [(100, 50), (1, 5), (400, 12)])
def test_timer_marks_subset_paired_by_the_clock_setting(first: int, count: int) -> None:
    # Every shift by whole marks pairs these photos equally well; the camera clock set to UTC
    # (to within a second) names the right one, and the solve says how it chose.
    marks = _timer_marks(589)
    res = photos.match(clockoffset.photo_times(_photos_at(marks[first:first + count], 0.3)), marks)
    assert [(p.photo, p.mark) for p in res.pairs] == [(k, first + k) for k in range(count)]
    assert not res.warnings
    assert len(res.notes) == 1 and "set to UTC" in res.notes[0]


def test_timer_marks_zone_clock_paired_by_the_clock_setting() -> None:
    # The camera clock on UTC-5 h: GPS - camera = 18 s + 5 h.
    marks = _timer_marks(300)
    res = photos.match(clockoffset.photo_times(_photos_at(marks[40:70], -5 * 3600 + 0.2)), marks)
    assert [(p.photo, p.mark) for p in res.pairs] == [(k, 40 + k) for k in range(30)]
    assert "UTC-5 h" in res.notes[0] and not res.warnings
    assert res.gps_minus_camera_s == pytest.approx(18 + 5 * 3600, abs=1.0)


def test_timer_marks_ambiguous_pairing_is_a_warning() -> None:
    # 0.9 s ahead: two shifts (2 s apart) both fit a clock set to UTC within its 1.5 s; no
    # single one can be named: a warning, never a silent pick.
    marks = _timer_marks(300)
    res = photos.match(clockoffset.photo_times(_photos_at(marks[50:80], 0.9)), marks)
    assert len(res.pairs) == 30
    assert len(res.warnings) == 1 and "ambiguous" in res.warnings[0]


def test_clock_offset_label_is_gps_minus_camera() -> None:
    # Photos stamped in UTC (right to the second): GPS - camera is the 18 leap seconds.
    marks = _timer_marks(100)
    ph = _photos_at(marks[10:20], 0.0)
    res = photos.match(clockoffset.photo_times(ph), marks)
    assert res.leap_s == 18
    assert res.gps_minus_camera_s == pytest.approx(18 - 0.35, abs=0.05)
    line = photos.reconciliation_lines(res, ph, marks)[0]
    assert line.startswith(f"camera clock offset (GPS - camera): {res.gps_minus_camera_s:+.2f} s")
    assert "18 s leap seconds (GPS - UTC)" in line


def test_duplicate_marks_dropped_and_reported() -> None:
    sc = photo_scenario(50, seed=3, subsec=True, missing_fraction=0.0, extra_fraction=0.0)
    ph = [
        exif.Photo(p.name, "", int(p.exif_datetime.replace(tzinfo=dt.UTC).timestamp()) * 10**9,
                     int(p.subsec or "0") * 10_000_000)
        for p in sc.photos
    ]
    marks: list[int | None] = [*sc.mark_t_gps_ns, sc.mark_t_gps_ns[10], None]
    res = photos.match(clockoffset.photo_times(ph), marks)
    assert res.duplicate_marks == (50,)
    assert len(res.pairs) == 50 and res.orphan_marks == ()
    lines = photos.reconciliation_lines(res, ph, marks)
    assert "1 duplicate marks dropped" in lines[2]


def test_burst_spread_by_file_order() -> None:
    second = 1_700_000_000 * 10**9
    ph = [exif.Photo(f"IMG_{i}.JPG", "", second) for i in range(4)]
    ph.append(exif.Photo("IMG_9.JPG", "", second + 10**9))
    t = clockoffset.photo_times(ph)
    frac = t.t_s - np.floor(t.t_s)
    assert frac[:4] == pytest.approx([0.10, 0.35, 0.65, 0.90], abs=1e-6)
    assert frac[4] == pytest.approx(0.5, abs=1e-6)
    assert not t.precise.any()


def test_read_photo_exif_fields(tmp_path: Path) -> None:
    p = tmp_path / "a.jpg"
    p.write_bytes(exif.make_jpeg(dt.datetime(2018, 10, 9, 14, 22, 5), subsec="37",
                                   offset_time="+02:00"))
    ph = exif.read_photo(p)
    assert ph.usable and ph.subsec_ns == 370_000_000 and ph.utc_offset_s == 7200
    assert ph.utc_second_ns == int(dt.datetime(2018, 10, 9, 12, 22, 5,
                                               tzinfo=dt.UTC).timestamp()) * 10**9
    (tmp_path / "b.jpg").write_bytes(exif.make_jpeg(None))
    (tmp_path / "c.jpg").write_bytes(b"not a jpeg")
    got = {x.name: x for x in exif.scan_photos(tmp_path)}
    assert got["b.jpg"].error and got["c.jpg"].error and not got["c.jpg"].usable


def test_jpeg_is_a_real_baseline_jpeg() -> None:
    data = exif.make_jpeg(dt.datetime(2020, 1, 1))
    assert data[:2] == b"\xff\xd8" and data[-2:] == b"\xff\xd9"
    assert b"\xff\xc0" in data and b"Exif\x00\x00" in data


def test_gps_copy_leaves_the_original_alone(tmp_path: Path) -> None:
    src = tmp_path / "IMG_1.JPG"
    src.write_bytes(exif.make_jpeg(dt.datetime(2020, 1, 1)))
    before = src.read_bytes()
    dst = tmp_path / "out" / "IMG_1.JPG"
    dst.parent.mkdir()
    exif.write_gps_copy(src, dst, 53.28044996, -9.05783633, 66.8)
    assert src.read_bytes() == before
    from exif import Image

    img = Image(dst.read_bytes())
    d, m, s = img.gps_latitude
    assert d + m / 60 + s / 3600 == pytest.approx(53.28044996, abs=1e-7)
    assert img.gps_longitude_ref == "W" and img.gps_altitude == pytest.approx(66.8)
    with pytest.raises(InputError):
        exif.write_gps_copy(src, src, 0.0, 0.0, 0.0)


def _jpeg_without_ifd1(when: str) -> bytes:
    """A JPEG whose EXIF is IFD0 -> Exif IFD (DateTimeOriginal) and nothing else: no thumbnail
    IFD (IFD1), as many cameras and editors write it (built by hand, big-endian)."""
    value = when.encode() + b"\x00"  # 20 bytes
    tiff = (
        b"MM\x00*" + (8).to_bytes(4, "big")
        # IFD0 at 8: one entry, ExifIFD pointer -> 26; next IFD 0
        + (1).to_bytes(2, "big") + bytes.fromhex("8769 0004 00000001") + (26).to_bytes(4, "big")
        + bytes(4)
        # Exif IFD at 26: DateTimeOriginal, ASCII 20 at 44
        + (1).to_bytes(2, "big") + bytes.fromhex("9003 0002 00000014") + (44).to_bytes(4, "big")
        + bytes(4) + value
    )
    plain = exif.make_jpeg(None)
    app1 = b"\xff\xe1" + (len(tiff) + 8).to_bytes(2, "big") + b"Exif\x00\x00" + tiff
    return plain[:20] + app1 + plain[20:]  # after SOI and the 16-byte JFIF APP0


def test_gps_copy_of_a_photo_without_thumbnail_ifd(tmp_path: Path) -> None:
    src = tmp_path / "IMG_7.JPG"
    src.write_bytes(_jpeg_without_ifd1("2018:10:09 12:26:24"))
    assert exif.read_photo(src).exif_second_ns > 0
    dst = tmp_path / "out.jpg"
    assert exif.write_gps_copy(src, dst, -33.85678, 151.21530, -12.25)
    from exif import Image

    img = Image(dst.read_bytes())
    d, m, sec = img.gps_latitude
    assert img.gps_latitude_ref == "S" and d + m / 60 + sec / 3600 == pytest.approx(33.85678)
    d, m, sec = img.gps_longitude
    assert img.gps_longitude_ref == "E" and d + m / 60 + sec / 3600 == pytest.approx(151.2153)
    assert img.gps_altitude == pytest.approx(12.25) and img.gps_altitude_ref == 1
    assert img.gps_map_datum == "WGS-84"
    # The capture time is still there and the image data is untouched.
    assert exif.read_photo(dst).exif_second_ns == exif.read_photo(src).exif_second_ns
    assert dst.read_bytes().endswith(src.read_bytes()[src.read_bytes().index(b"\xff\xdb"):])
    # Written again (a re-run on a copy): the new position replaces the old.
    again = tmp_path / "again.jpg"
    assert exif.write_gps_copy(dst, again, 10.5, -20.25, 3.0)
    img = Image(again.read_bytes())
    assert img.gps_latitude == (10.0, 30.0, 0.0) and img.gps_longitude_ref == "W"


def test_gps_copy_keeps_the_thumbnail_ifd(tmp_path: Path) -> None:
    # Chain an IFD1 (one entry: Compression = 6, JPEG thumbnail) after IFD0 by hand.
    plain = _jpeg_without_ifd1("2018:10:09 12:26:24")
    at = plain.index(b"MM\x00*")
    seg_len = int.from_bytes(plain[at - 8 : at - 6], "big")
    tiff = bytearray(plain[at : at - 8 + seg_len])
    ifd1_at = len(tiff)
    tiff[22:26] = ifd1_at.to_bytes(4, "big")  # IFD0's next-IFD field
    tiff += (1).to_bytes(2, "big") + bytes.fromhex("0103 0003 00000001 0006 0000") + bytes(4)
    body = b"Exif\x00\x00" + bytes(tiff)
    src = tmp_path / "a.jpg"
    src.write_bytes(plain[: at - 10] + b"\xff\xe1" + (len(body) + 2).to_bytes(2, "big") + body
                    + plain[at - 8 + seg_len :])
    assert exif.read_photo(src).usable
    dst = tmp_path / "b.jpg"
    assert exif.write_gps_copy(src, dst, 1.0, 2.0, 3.0)
    out = dst.read_bytes()
    t = out[out.index(b"MM\x00*") :]
    ifd0 = int.from_bytes(t[4:8], "big")
    n = int.from_bytes(t[ifd0 : ifd0 + 2], "big")
    at1 = int.from_bytes(t[ifd0 + 2 + 12 * n : ifd0 + 6 + 12 * n], "big")
    assert at1 > 0  # IFD1 still chained after IFD0, its entry as it was
    entries = {t[at1 + 2 + 12 * k: at1 + 4 + 12 * k]: t[at1 + 2 + 12 * k: at1 + 14 + 12 * k]
               for k in range(int.from_bytes(t[at1: at1 + 2], "big"))}
    assert entries[b"\x01\x03"] == bytes.fromhex("0103 0003 00000001 0006 0000")
    from exif import Image

    assert Image(out).gps_altitude == pytest.approx(3.0)


def test_gps_copy_of_a_damaged_exif_is_skipped_with_a_warning(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    src = tmp_path / "IMG_9.JPG"
    good = _jpeg_without_ifd1("2018:10:09 12:26:24")
    at = good.index(b"MM\x00*")
    src.write_bytes(good[: at + 4] + (9999).to_bytes(4, "big") + good[at + 8 :])  # IFD0 nowhere
    dst = tmp_path / "out.jpg"
    assert not exif.write_gps_copy(src, dst, 1.0, 2.0, 3.0)
    assert not dst.exists()
    warned = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert len(warned) == 1 and warned[0].startswith("IMG_9.JPG: no copy with GPS tags written")


def test_scan_requires_a_directory(tmp_path: Path) -> None:
    with pytest.raises(InputError):
        exif.scan_photos(tmp_path / "missing")


def test_natural_order() -> None:
    names = ["IMG_10.JPG", "IMG_9.JPG", "img_100.jpg"]
    assert sorted(names, key=exif.natural_key) == ["IMG_9.JPG", "IMG_10.JPG", "img_100.jpg"]


@pytest.mark.parametrize("subsec", [False, True])
def test_residual_sigma_is_that_of_the_pairs(tmp_path: Path, subsec: bool) -> None:
    """One residual σ: the robust σ of the final pairs' residuals, whatever the photos' timing.

    Whole-second photos used to report the pairing cap (0.750 s) as their σ while the report
    computed the pairs' own spread (a few ms)."""
    sc = photo_scenario(120, seed=5, subsec=subsec, missing_fraction=0.0, extra_fraction=0.0)
    res = _run(sc, tmp_path)
    r = np.array([p.residual_s for p in res.pairs])
    assert res.residual_sigma_s == pytest.approx(clockoffset.residual_sigma_s(r), abs=1e-12)
    assert res.residual_sigma_s == pytest.approx(
        1.4826 * float(np.median(np.abs(r - np.median(r)))), abs=1e-12)
    assert res.residual_sigma_s < clockoffset.MAX_PAIR_S / 2
    line = photos.reconciliation_lines(res, exif.scan_photos(tmp_path), sc.mark_t_gps_ns)[1]
    assert f"timing residual sigma {res.residual_sigma_s * 1e3:.1f} ms (robust)" in line


def test_residual_sigma_needs_three_pairs() -> None:
    assert np.isnan(clockoffset.residual_sigma_s(np.array([0.1, 0.2])))
    assert clockoffset.residual_sigma_text(float("nan")) == "not computed (fewer than 3 pairs)"
