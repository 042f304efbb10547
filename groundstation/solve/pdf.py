"""``report.pdf``: the report's HTML printed by headless Chromium (``--print-to-pdf``), so the
paper copy is exactly the page. Without Chromium no PDF is written and the caller says so.
"""

from __future__ import annotations

import shutil
import subprocess
import tempfile
from pathlib import Path

CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
"""Executables tried, in order, for printing the PDF."""
PDF_TIMEOUT_S = 120.0


def find_chromium() -> str | None:
    """Path of a Chromium (or Chrome) executable, None when none is installed."""
    for name in CHROMIUM_NAMES:
        path = shutil.which(name)
        if path:
            return path
    return None


def print_pdf(html_path: Path, pdf_path: Path, chromium: str) -> None:
    """Print a page to PDF with headless Chromium (A4 from the page's ``@page`` rule).

    Raises:
        RuntimeError: Chromium failed or wrote nothing (message names why).
    """
    with tempfile.TemporaryDirectory(prefix="gs-report-") as profile:
        cmd = [chromium, "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
               "--disable-background-networking", "--disable-component-update",
               "--disable-sync", f"--user-data-dir={profile}", "--no-pdf-header-footer",
               f"--print-to-pdf={pdf_path}", html_path.resolve().as_uri()]
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=PDF_TIMEOUT_S,
                                  check=False)
        except subprocess.TimeoutExpired as err:
            raise RuntimeError(f"Chromium did not finish within {PDF_TIMEOUT_S:g} s") from err
    if proc.returncode != 0 or not pdf_path.is_file() or pdf_path.stat().st_size == 0:
        tail = (proc.stderr or "").strip().splitlines()[-1:] or ["no output"]
        raise RuntimeError(f"Chromium exit {proc.returncode}: {tail[0]}")
