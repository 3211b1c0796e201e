"""Deterministic sessions written as captures (layer 3): :mod:`.beacon` (SharedLink UDP
beacons, ``sharedlink gen``), :mod:`.serial` (a SharedLink point-to-point serial session),
:mod:`.p2os` and :mod:`.blackboard` (client/server sessions), with the drive they share in
:mod:`.scenario`. The same options and seed give the same bytes."""
