"""What users ask of a capture (layer 4): :mod:`.decode` (every frame with the variable table
after it: :func:`~.decode.iter_decoded`), :mod:`.stats` (``sharedlink stats``), :mod:`.diff`
(``sharedlink diff``), :mod:`.transform` (``compress``/``expand``), :mod:`.export` (CSV, JSON
Lines, GeoJSON, KML and, with :mod:`.mcap_export` and :mod:`.foxglove_channels`, MCAP) and
:mod:`.plot`. Each reads a capture once, front to back, and reports damage after what came
before it (see ``docs/architecture.md``)."""
