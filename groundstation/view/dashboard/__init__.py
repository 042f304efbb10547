"""The operator's web dashboard: a local page fed live from Zenoh (server, state, static page)."""

from groundstation.view.dashboard.server import Dashboard, DashboardSettings, Hub
from groundstation.view.dashboard.state import StationView

__all__ = ["Dashboard", "DashboardSettings", "Hub", "StationView"]
