"""The solve's printed notes in plain words: the engine's other cases (the user's or the default
motion model, conditioning not applied, hidden slips and Doppler bridges) and .pos layouts."""

from __future__ import annotations

from groundstation.solve.report_notes import engine_lines, pos_format_line


def test_other_engine_cases_in_plain_words() -> None:
    lines = engine_lines({
        "conditioning": {"applied": True, "totals": {
            "receiver_slips": 3, "hidden_found": 2, "repaired": 4, "flagged": 1,
            "half_resolved": 0, "kept_by_doppler": 5},
            "satellites": {"G05": {"repaired": 1, "hidden_found": 2, "flagged": 1},
                           "G09": {"repaired": 0, "hidden_found": 0, "flagged": 0}}},
        "dynamics": {"measured": None, "used": {"stats-prnaccelh": "1.5",
                                                "stats-prnaccelv": "0.4"},
                     "user": ["stats-prnaccelh", "stats-prnaccelv"]},
    })
    assert lines == [
        ("carrier phase checked before solving: 3 cycle slips marked by the receiver, 2 more "
        "found where the phase was missing (radio gaps, blank epochs); 4 phase jumps repaired, "
        "0 half-cycle ambiguities resolved, 1 "
        "breaks not bridged (the engine restarts those satellites), 5 gaps bridged on the "
        "Doppler alone"),
        "by satellite: G05 1 repaired, 2 found in gaps, 1 not bridged",
        "motion model: your own engine setting 1.5 / 0.4 horizontal / vertical",
    ]
    assert engine_lines({
        "conditioning": {"applied": False, "note": "not applied (no broadcast ephemeris)"},
        "dynamics": {"measured": None, "used": {"a": "0.3", "b": "0.05"}},
    }) == [
        "carrier phase not repaired before solving: not applied (no broadcast ephemeris)",
        ("motion model: the engine's default setting 0.3 / 0.05 horizontal / vertical (the "
        "rover's motion could not be measured)"),
    ]


def test_pos_layouts_in_plain_words() -> None:
    assert pos_format_line("RTKLIB .pos (llh, UTC, tow)") == (
        "solution file in RTKLIB format (latitude/longitude/height, UTC, GPS week and seconds)")
    assert pos_format_line("RTKLIB .pos (odd)") == "RTKLIB .pos (odd)"
