"""groundstation: UAV photogrammetry ground station and post-flight solver."""

__version__ = "0.1.0"
