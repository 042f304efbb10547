"""The report's colours, shared by its figures (:mod:`.figures`) and its tables.

Apart from the figures so that the tables, and a solve that stops before drawing anything,
do not load matplotlib.
"""

from __future__ import annotations

QUALITY_COLOURS = {1: "#1a9850", 2: "#f39c12", 3: "#74add1", 4: "#4575b4", 5: "#d73027",
                   6: "#8073ac", 0: "#7f7f7f"}
"""Colour per RTKLIB quality (fix green, float orange, single red), shared by every figure."""
GRADE_COLOURS = {"fixed": "#1a9850", "fixed-unchecked": "#2c7fb8", "float": "#f39c12",
                 "single": "#d73027", "none": "#7f7f7f"}
"""Colour per grade (the integrity stage's; checked fixes green, unchecked ones blue)."""
