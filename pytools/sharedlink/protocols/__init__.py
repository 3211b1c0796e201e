"""The codecs (layer 1): bytes in, frozen dataclasses out, and back. :mod:`.codec` is SharedLink
(``parse_frame``/``build_frame``, checksums), :mod:`.p2os` the Pioneer P2OS packets,
:mod:`.blackboard` the Holland blackboard messages, and :mod:`.state` the shared-variable table
that value frames update (with ``parse_variables``, the one reader of ``--variables``). A codec
raises only its own :class:`sharedlink.errors.DecodeError`, whatever the input."""
