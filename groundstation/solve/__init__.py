"""Post-flight solver: positions -> marks -> photos -> lever arm -> outputs (see pipeline.py)."""
