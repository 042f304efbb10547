"""Our own carrier-phase solution over whole arcs: the check of every fix, and fixes of its own.

The package turns a rover's conditioned observations and its base's into positions whose
"fixed" is argued from the whole flight's data rather than from a filter's ratio test:

- :mod:`.table`: the between-receiver phase and code per epoch and GPS satellite, in arcs;
- :mod:`.normal`: every arc's constant from all epochs at once (float), epochs eliminated;
- :mod:`.steps`: slips nobody flagged, found as steps and split off;
- :mod:`.lattice`: the sure integer combinations (LAMBDA decorrelation, partial bootstrapping);
- :mod:`.epochs`: each epoch's position given the constants, with their uncertainty.

:func:`.arcs.resolve` runs them in that order; :mod:`.grade` names what a position may be
called (imported alone by the exports and the report: this package itself imports nothing).
"""
