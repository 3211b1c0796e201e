"""The decoding core, by part (docs/architecture.md, "The decoding core"; the public names are
:mod:`sharedlink.analysis.decode`'s):

- ``records``: a capture's records (the one classic-pcap walker, :mod:`sharedlink.capture.pcap_blocks`);
- ``decoded``: :class:`~sharedlink.analysis.core.decoded.Decoded`, what a frame gives;
- ``reference``: the reference path (``ReferenceDecoder``, frame by frame through ``LinkState``);
- ``direction``: one direction as the fast tiers follow it (its layouts, its sync clock);
- ``checksum``, ``patterns``: the one checksum rule and record test of the fast tiers;
- ``fastpath``, ``counts``, ``columns``, ``compiled`` (with ``lanes``): the fast tiers in front of the
  reference path, one a mode (Decoded frames, counts, columns, changes); ``expand``: expand's run
  taker, on the counts and columns tiers' lanes;
- ``decoder``: ``Decoder``, the whole; ``capture``: its record loop; ``timefmt``: times as written.
"""
