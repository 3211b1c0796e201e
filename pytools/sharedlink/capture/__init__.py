"""Files and devices (layer 2): :mod:`.pcapio` reads and writes pcap/pcapng records (times in
integer nanoseconds), :mod:`.packets` takes Ethernet/IP/UDP/TCP apart, :mod:`.serial_format`
holds the serial capture format and its deframers (``docs/serial-capture-format.md``),
:mod:`.serial_port` captures a live line, :mod:`.serial_import` converts serial logs, and
:mod:`.stream` turns records into datagrams and frames (and holds the chunks of change records
``diff`` reads, whose format is :mod:`.change_records`; their reader decodes through the core,
:mod:`sharedlink.analysis.changes`)."""
