"""Files and devices (layer 2): :mod:`.pcapio` reads and writes pcap/pcapng records (times in
integer nanoseconds), :mod:`.packets` takes Ethernet/IP/UDP/TCP apart, :mod:`.serial_format`
holds the serial capture format and its deframers (``docs/serial-capture-format.md``),
:mod:`.serial_port` captures a live line, :mod:`.serial_import` converts serial logs, and
:mod:`.stream` turns records into datagrams, frames and value changes (with its fast tiers
:mod:`.fast_records`, :mod:`.fast_blocks` and the record format :mod:`.change_records`)."""
