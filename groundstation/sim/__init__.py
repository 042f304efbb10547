"""The simulator: a GPS constellation, a rover and a base receiver, and their u-blox streams.

Entry point: :func:`groundstation.sim.stream.simulate` with a
:class:`~groundstation.sim.stream.SimConfig`; :func:`groundstation.pacing.paced` replays its
timed chunks in real time, :class:`groundstation.sim.ptylink.PtyLink` serves them on a pty.
:func:`groundstation.sim.profiles.sim_config` builds the configuration of a named profile
(``default``, ``seed``).
"""
