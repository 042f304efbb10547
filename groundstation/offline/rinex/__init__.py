"""UBX recording -> RINEX 2.11/3.04 observation and navigation files and the time-mark table.

One module per concern: :mod:`.observations` (messages to observations, RTKLIB's rules and the
shared phase rule), :mod:`.format` (number and line formatting), :mod:`.obs_writer` and
:mod:`.nav_writer` (the two files), :mod:`.marks_table` (the marks CSV), :mod:`.convert` (the
whole conversion) and :mod:`.reader` (reading RINEX 3 back). The conversion's entry points are
and its public pieces are re-exported here.
"""

from groundstation.offline.rinex.convert import (
    RinexOptions,
    RinexResult,
    convert,
    events_after_spacing_change,
    read_frames,
    read_recording,
)
from groundstation.offline.rinex.nav_writer import write_nav
from groundstation.offline.rinex.obs_writer import RINEX_VERSIONS, HeaderInfo, write_obs
from groundstation.offline.rinex.observations import ObsSet, obs_from_raw, obs_from_rawx
from groundstation.offline.rinex.reader import ObsEpoch, read_obs3

__all__ = [
    "RINEX_VERSIONS",
    "HeaderInfo",
    "ObsEpoch",
    "ObsSet",
    "RinexOptions",
    "RinexResult",
    "convert",
    "events_after_spacing_change",
    "obs_from_raw",
    "obs_from_rawx",
    "read_obs3",
    "read_frames",
    "read_recording",
    "write_nav",
    "write_obs",
]
