"""A synthetic sky for the integrity stage's tests: GPS-like satellites over a site, with the
ranges and lines of sight :class:`~groundstation.solve.integrity.table.PhaseTable` asks its
geometry for."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


class Sky:
    """Satellites 20 000 km from the site along directions that turn slowly, as GPS does."""

    def __init__(self, site: FloatArray, t_s: FloatArray, n_sv: int,
                 rng: np.random.Generator) -> None:
        up = site / np.linalg.norm(site)
        east = np.cross([0.0, 0.0, 1.0], up)
        east /= np.linalg.norm(east)
        north = np.cross(up, east)
        az = rng.uniform(0, 2 * np.pi, n_sv)[None] + rng.uniform(-1, 1, n_sv)[None] * 1e-4 * (
            t_s[:, None])
        el = rng.uniform(np.radians(25), np.radians(80), n_sv)[None] + 0.3e-4 * t_s[:, None]
        d = (np.cos(el)[..., None] * (np.sin(az)[..., None] * east
                                      + np.cos(az)[..., None] * north)
             + np.sin(el)[..., None] * up)
        self.pos = site + 2.0e7 * d
        self.clk_m = np.zeros(self.pos.shape[:2])

    def ranges_all(self, x: FloatArray) -> tuple[FloatArray, FloatArray]:
        xx = np.broadcast_to(np.asarray(x, dtype=np.float64), (self.pos.shape[0], 3))
        d = self.pos - xx[:, None, :]
        rho = np.linalg.norm(d, axis=2)
        return rho - self.clk_m, d / rho[..., None]
