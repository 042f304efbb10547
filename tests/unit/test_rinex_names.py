"""Names from outside (a file name, a marker) in RINEX headers, which hold ASCII only: a
surveyor's town with an umlaut or a tab in a marker must not stop the conversion."""

from __future__ import annotations

from pathlib import Path

from groundstation.cli import main
from groundstation.offline.rinex.format import ascii_text, hl
from groundstation.sim.profiles import sim_config
from groundstation.sim.stream import simulate


def test_header_text_is_folded_to_ascii() -> None:
    assert ascii_text("Flug_Görlitz Ærø\t東京") == "Flug_Gorlitz ?r????"
    line = hl("Görlitz", "MARKER NAME")
    assert line.isascii() and len(line) == 81 and line.startswith("Gorlitz ")


def test_a_recording_with_an_accented_name_converts(tmp_path: Path) -> None:
    src = tmp_path / "Flug_Görlitz.ubx"
    src.write_bytes(simulate(sim_config(duration_s=30.0)).rover_bytes)
    assert main(["rinex", str(src), "--out-dir", str(tmp_path / "out"),
                 "--marker", "Görlitz Süd"]) == 0
    text = (tmp_path / "out" / "Flug_Görlitz.obs").read_text(encoding="ascii")
    assert "converted from Flug_Gorlitz.ubx" in text
    assert "Gorlitz Sud" + " " * 49 + "MARKER NAME" in text
