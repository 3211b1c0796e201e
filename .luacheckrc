-- luacheck configuration for the Wireshark Lua dissector (Lua 5.2 in Wireshark 4.0, 5.4 in 4.4+)
std = "lua52+lua54"
max_line_length = 120
read_globals = {
    -- Wireshark wslua API
    "Proto", "ProtoField", "ProtoExpert", "Pref", "DissectorTable", "Dissector", "Field",
    "Int64", "UInt64", "NSTime", "ByteArray", "Tvb", "TvbRange", "TreeItem", "Pinfo", "Address",
    "Column", "Columns", "Listener", "register_postdissector",
    "base", "expert", "frametype", "ftypes", "bit",
    "DESEGMENT_ONE_MORE_SEGMENT", "ENC_ASCII", "ENC_UTF_8", "ENC_NA", "ENC_BIG_ENDIAN", "ENC_LITTLE_ENDIAN",
    "get_version", "set_plugin_info", "info", "warn", "message", "debug", "critical", "report_failure", "Dir",
    "gui_enabled",
}

-- issue 27's shape for the three small dissectors (tests/dissector/test_shape_small.py)
files["dissector/p2os.lua"] = { max_cyclomatic_complexity = 20 }
files["dissector/blackboard.lua"] = { max_cyclomatic_complexity = 20 }
files["dissector/serial.lua"] = { max_cyclomatic_complexity = 20 }
files["dissector/robots/p2os_dissect.lua"] = { max_cyclomatic_complexity = 20 }
files["dissector/robots/blackboard_dissect.lua"] = { max_cyclomatic_complexity = 20 }
files["dissector/robots/serial_dissect.lua"] = { max_cyclomatic_complexity = 20 }
