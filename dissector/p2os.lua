-- P2OS (Pioneer robot) dissector for Wireshark 4.0+ (Lua 5.2 .. 5.4).
--
-- Packet: FA FB, count (bytes that follow, checksum included), payload, checksum (2 bytes,
-- high byte first). Client commands: number + optional argument (0x3B + u16 positive int,
-- 0x1B + u16 negative int, 0x2B + length + string). Server packets: type byte, then the
-- standard SIP (0x32 stopped, 0x33 moving), SYNC echoes (0..2, the SYNC2 echo with the robot's
-- name, class and subclass), CONFIG (0x20), ENCODER (0x90); others shown raw.
--
-- Transports: TCP port 8101 (MobileSim; preference) with reassembly and several packets per
-- segment; a heuristic on the FA FB header with a checksum check (TCP and UDP); and any bare
-- byte buffer through Dissector.get("p2os") (serial captures).
--
-- Direction (client to robot: a command; robot to client: a server packet): the TCP port
-- preference, else the capture's direction flag (serial: outbound = client), else the content.
--
-- Field reference: docs/fields-p2os-blackboard.md. Needs robots/p2os_rules.lua beside it (the
-- framing rules it shares with serial.lua) and robots/p2os_dissect.lua (its dissection, run on
-- the first packet that needs it); sharedlink plugins install copies them.
-- Twins (code that must exist in two self-contained files; tests/dissector/test_lua_twins.py
-- shows they agree): istr, u8 <-> blackboard.lua.
-- File order (../shared/STYLE.md): header, plugin info, Proto and tables, fields and experts,
-- preferences, the twins, the dissection (robots/p2os_dissect.lua: state, helpers, dissect_*,
-- the buffer dissector, heuristic), registration.

-- luacheck: read globals Proto ProtoField ProtoExpert Pref DissectorTable base expert bit
-- luacheck: read globals DESEGMENT_ONE_MORE_SEGMENT set_plugin_info

if set_plugin_info then
    set_plugin_info({
        version = "1.3.0",
        description = "P2OS (Pioneer robot protocol) over TCP, UDP and serial captures",
        author = "SharedLink analyzer project",
        repository = "dissector/p2os.lua",
    })
end

local p2os = Proto("p2os", "P2OS (Pioneer robot protocol)")

-- The P2OS framing rules (checksum, resynchronisation, direction from the content), written once
-- for this file and serial.lua: robots/p2os_rules.lua beside this file, run by dissection()
-- below with the dissection (a copy of our own: no state shared with serial.lua).
local HERE = (debug.getinfo(1, "S").source or ""):match("^@(.*[/\\])") or ""
-- robots/NAME.lua beside this file, compiled (Wireshark's loadfile raises where Lua's returns nil
-- and the reason)
local function robot_chunk(name)
    local ok, chunk, err = pcall(loadfile, HERE .. "robots/" .. name .. ".lua")
    if not ok or not chunk then
        err = tostring(ok and err or chunk)
        error("p2os.lua needs robots/" .. name .. ".lua beside it (sharedlink plugins install copies both): " .. err)
    end
    return chunk
end
robot_chunk("p2os_rules")   -- (compiled and dropped: it is there and parses)

local COMMANDS = {
    [0] = "PULSE", [1] = "OPEN", [2] = "CLOSE", [3] = "POLLING", [4] = "ENABLE", [5] = "SETA",
    [6] = "SETV", [7] = "SETO", [8] = "MOVE", [9] = "ROTATE", [10] = "SETRV", [11] = "VEL",
    [12] = "HEAD", [13] = "DHEAD", [15] = "SAY", [17] = "JOYREQUEST", [18] = "CONFIG",
    [19] = "ENCODER", [20] = "SETRVDIR", [21] = "RVEL", [22] = "DCHEAD", [23] = "SETRA",
    [28] = "SONAR", [29] = "STOP", [30] = "DIGOUT", [32] = "VEL2", [33] = "GRIPPER",
    [35] = "ADSEL", [36] = "GRIPPERVAL", [37] = "GRIPREQUEST", [40] = "IOREQUEST",
    [41] = "PTUPOS", [42] = "TTY2", [43] = "GETAUX", [44] = "BUMPSTALL", [45] = "TCM2",
    [47] = "JOYDRIVE", [48] = "SONARCYCLE", [50] = "HOSTBAUD", [51] = "AUX1BAUD",
    [52] = "AUX2BAUD", [53] = "AUX3BAUD", [55] = "E_STOP", [56] = "M_STALL",
    [58] = "GYROREQUEST", [59] = "LCDWRITE", [60] = "TTY4", [61] = "GETAUX3",
}
-- before OPEN, commands 0..2 are the connection handshake
local SYNC_NAMES = { [0] = "SYNC0", [1] = "SYNC1", [2] = "SYNC2" }

local ARG_POSITIVE, ARG_NEGATIVE, ARG_STRING = 0x3B, 0x1B, 0x2B
local ARG_TYPES = { [ARG_POSITIVE] = "positive int", [ARG_NEGATIVE] = "negative int", [ARG_STRING] = "string" }

local TYPE_CONFIG, TYPE_SIP_STOPPED, TYPE_SIP_MOVING, TYPE_ENCODER = 0x20, 0x32, 0x33, 0x90
local SERVER_TYPES = {
    [0x00] = "SYNC0 echo", [0x01] = "SYNC1 echo", [0x02] = "SYNC2 echo", [0x20] = "CONFIG",
    [0x32] = "standard SIP (stopped)", [0x33] = "standard SIP (moving)", [0x80] = "VISION",
    [0x90] = "ENCODER", [0x8D] = "JOYSTICK", [0xE0] = "GRIPPER", [0xF0] = "IO",
}

local DEGREES_PER_UNIT = 360.0 / 4096.0

-- p2os.direction values, and the Info column's prefix for each direction
local DIRECTION_NAMES = { [0] = "client to robot (command)", [1] = "robot to client (server packet)" }
local DIRECTION_INFO = { [0] = "Client\226\134\146Robot ", [1] = "Robot\226\134\146Client " } -- U+2192

-- ---------------------------------------------------------------------------------------------
-- fields (registered once, at load time)

local pf = {
    header = ProtoField.uint16("p2os.header", "Header", base.HEX),
    count = ProtoField.uint8("p2os.count", "Byte count", base.DEC),
    payload = ProtoField.bytes("p2os.payload", "Payload"),
    checksum = ProtoField.uint16("p2os.checksum", "Checksum", base.HEX),
    checksum_calc = ProtoField.uint16("p2os.checksum.calculated", "Calculated checksum", base.HEX),
    checksum_status = ProtoField.uint8("p2os.checksum.status", "Checksum status", base.DEC,
        { [0] = "Bad", [1] = "Good", [2] = "Unverified" }),
    direction = ProtoField.uint8("p2os.direction", "Direction", base.DEC, DIRECTION_NAMES),
    command = ProtoField.uint8("p2os.command", "Command", base.DEC, COMMANDS),
    command_name = ProtoField.string("p2os.command.name", "Command name"),
    argtype = ProtoField.uint8("p2os.argtype", "Argument type", base.HEX, ARG_TYPES),
    arg_int = ProtoField.int32("p2os.arg.int", "Argument", base.DEC),
    arg_length = ProtoField.uint8("p2os.arg.length", "String length", base.DEC),
    arg_string = ProtoField.string("p2os.arg.string", "Argument string"),
    arg_terminator = ProtoField.uint8("p2os.arg.terminator", "String terminator (NUL)", base.HEX),
    arg_data = ProtoField.bytes("p2os.arg.data", "Argument data"),
    extra = ProtoField.bytes("p2os.extra", "Extra bytes"),
    type = ProtoField.uint8("p2os.type", "Packet type", base.HEX, SERVER_TYPES),
    sync = ProtoField.uint8("p2os.sync", "SYNC echo", base.DEC),
    robot_name = ProtoField.string("p2os.robot.name", "Robot name"),
    robot_class = ProtoField.string("p2os.robot.class", "Robot class"),
    robot_subclass = ProtoField.string("p2os.robot.subclass", "Robot subclass"),
    sip_moving = ProtoField.bool("p2os.sip.moving", "Motors moving"),
    sip_xpos = ProtoField.uint16("p2os.sip.xpos", "X position (mm)", base.DEC),
    sip_ypos = ProtoField.uint16("p2os.sip.ypos", "Y position (mm)", base.DEC),
    sip_thpos = ProtoField.int16("p2os.sip.thpos", "Heading (raw, 4096 per turn)", base.DEC),
    sip_heading = ProtoField.double("p2os.sip.heading", "Heading (degrees)"),
    sip_lvel = ProtoField.int16("p2os.sip.lvel", "Left wheel velocity (mm/s)", base.DEC),
    sip_rvel = ProtoField.int16("p2os.sip.rvel", "Right wheel velocity (mm/s)", base.DEC),
    sip_battery = ProtoField.uint8("p2os.sip.battery", "Battery (0.1 V)", base.DEC),
    sip_volts = ProtoField.double("p2os.sip.volts", "Battery (V)"),
    sip_stall = ProtoField.uint16("p2os.sip.stall_bumpers", "Stall and bumpers", base.HEX),
    sip_stall_left = ProtoField.bool("p2os.sip.stall.left", "Left wheel stalled", 16, nil, 0x0001),
    sip_stall_right = ProtoField.bool("p2os.sip.stall.right", "Right wheel stalled", 16, nil, 0x0100),
    sip_control = ProtoField.int16("p2os.sip.control", "Control (heading setpoint)", base.DEC),
    sip_flags = ProtoField.uint16("p2os.sip.flags", "Flags", base.HEX),
    sip_motors = ProtoField.bool("p2os.sip.flags.motors", "Motors enabled", 16, nil, 0x0001),
    sip_compass = ProtoField.uint8("p2os.sip.compass", "Compass (2-degree units)", base.DEC),
    sip_sonar_count = ProtoField.uint8("p2os.sip.sonar.count", "Sonar readings", base.DEC),
    sip_sonar_number = ProtoField.uint8("p2os.sip.sonar.number", "Sonar number", base.DEC),
    sip_sonar_range = ProtoField.uint16("p2os.sip.sonar.range", "Sonar range (mm)", base.DEC),
    sip_grip = ProtoField.uint8("p2os.sip.grip_state", "Gripper state", base.HEX),
    sip_anport = ProtoField.uint8("p2os.sip.anport", "Analog port", base.DEC),
    sip_analog = ProtoField.uint8("p2os.sip.analog", "Analog value", base.DEC),
    sip_digin = ProtoField.uint8("p2os.sip.digin", "Digital inputs", base.HEX),
    sip_digout = ProtoField.uint8("p2os.sip.digout", "Digital outputs", base.HEX),
    sip_extra = ProtoField.bytes("p2os.sip.extra", "Optional fields (not decoded)"),
    enc_left = ProtoField.int32("p2os.encoder.left", "Left encoder", base.DEC),
    enc_right = ProtoField.int32("p2os.encoder.right", "Right encoder", base.DEC),
    data = ProtoField.bytes("p2os.data", "Data"),
    junk = ProtoField.bytes("p2os.junk", "Bytes outside any packet"),
    outage_duration = ProtoField.double("p2os.outage.duration", "Outage duration (s)"),
}

-- CONFIG packet: leading fields in ARIA's order (the rest shown raw)
local CONFIG_FIELDS = {
    { "robot_type", "s", "Robot type" }, { "subtype", "s", "Subtype" }, { "serial", "s", "Serial number" },
    { "four_mots", 1, "Four motors" }, { "rotvel_top", 2, "Max rotational velocity (deg/s)" },
    { "transvel_top", 2, "Max translational velocity (mm/s)" },
    { "rotaccel_top", 2, "Max rotational acceleration" }, { "transaccel_top", 2, "Max translational acceleration" },
    { "pwm_max", 2, "Max PWM" }, { "name", "s", "Robot name" }, { "sip_cycle", 1, "SIP cycle (ms)" },
    { "host_baud", 1, "Host baud code" }, { "aux_baud", 1, "AUX baud code" }, { "gripper", 2, "Gripper" },
    { "front_sonar", 2, "Front sonar" }, { "rear_sonar", 1, "Rear sonar" },
    { "low_battery", 2, "Low battery (0.1 V)" }, { "revcount", 2, "Revcount" }, { "watchdog", 2, "Watchdog (ms)" },
}
local config_pf = {}
for _, c in ipairs(CONFIG_FIELDS) do
    local abbr = "p2os.config." .. c[1]
    local f
    if c[2] == "s" then
        f = ProtoField.string(abbr, c[3])
    elseif c[2] == 1 then
        f = ProtoField.uint8(abbr, c[3], base.DEC)
    else
        f = ProtoField.uint16(abbr, c[3], base.DEC)
    end
    config_pf[c[1]] = f
    pf["config_" .. c[1]] = f
end
pf.config_extra = ProtoField.bytes("p2os.config.extra", "Further CONFIG fields (not decoded)")

local field_list = {}
for _, f in pairs(pf) do
    field_list[#field_list + 1] = f
end
p2os.fields = field_list

local ex = {
    checksum_bad = ProtoExpert.new("p2os.checksum.bad", "Bad checksum", expert.group.CHECKSUM, expert.severity.ERROR),
    count_big = ProtoExpert.new("p2os.count.too_big", "Byte count over 200: P2OS ignores this packet",
        expert.group.PROTOCOL, expert.severity.WARN),
    count_small = ProtoExpert.new("p2os.count.too_small", "Byte count below 2 leaves no room for the checksum",
        expert.group.MALFORMED, expert.severity.ERROR),
    truncated = ProtoExpert.new("p2os.truncated", "Packet truncated", expert.group.MALFORMED, expert.severity.ERROR),
    empty = ProtoExpert.new("p2os.empty", "Empty payload", expert.group.MALFORMED, expert.severity.WARN),
    arg_truncated = ProtoExpert.new("p2os.arg.truncated", "Argument truncated", expert.group.MALFORMED,
        expert.severity.ERROR),
    arg_unknown = ProtoExpert.new("p2os.arg.unknown", "Unknown argument type", expert.group.PROTOCOL,
        expert.severity.WARN),
    extra = ProtoExpert.new("p2os.extra.bytes", "Bytes after the expected end", expert.group.PROTOCOL,
        expert.severity.WARN),
    unknown_command = ProtoExpert.new("p2os.command.unknown", "Unknown command number", expert.group.UNDECODED,
        expert.severity.NOTE),
    unknown_type = ProtoExpert.new("p2os.type.unknown", "Server packet type not decoded", expert.group.UNDECODED,
        expert.severity.NOTE),
    sip_truncated = ProtoExpert.new("p2os.sip.truncated", "Server packet truncated", expert.group.MALFORMED,
        expert.severity.ERROR),
    junk = ProtoExpert.new("p2os.junk.bytes", "Bytes outside any P2OS packet", expert.group.MALFORMED,
        expert.severity.WARN),
    direction_guess = ProtoExpert.new("p2os.direction.guessed", "Direction guessed from the content",
        expert.group.SEQUENCE, expert.severity.CHAT),
    limit = ProtoExpert.new("p2os.limit", "Limit exceeded", expert.group.PROTOCOL, expert.severity.WARN),
    outage = ProtoExpert.new("p2os.outage", "Link silent", expert.group.SEQUENCE, expert.severity.WARN),
}
local expert_list = {}
for _, e in pairs(ex) do
    expert_list[#expert_list + 1] = e
end
p2os.experts = expert_list

-- ---------------------------------------------------------------------------------------------
-- preferences and per-capture state

p2os.prefs.tcp_port = Pref.uint("MobileSim TCP port", 8101, "TCP port of the P2OS server (MobileSim: 8101; 0: none)")
p2os.prefs.max_conversations = Pref.uint("Max conversations", 65536,
    "Conversations whose SYNC2 echo is remembered; past it a conversation's commands 0..2 keep their SYNC names")

-- ---------------------------------------------------------------------------------------------
-- helpers: every tvb access goes through a length check

-- <twin: blackboard.lua istr>
local function istr(n)
    return tostring(math.floor(n))
end

-- <twin: blackboard.lua u8>
local function u8(tvb, off)
    return tvb:range(off, 1):uint()
end

-- ---------------------------------------------------------------------------------------------
-- the dissection: robots/p2os_dissect.lua (the per-capture state, the other helpers, dissect_*,
-- the buffer dissector, the heuristic), run on the first packet that needs it, so that a capture
-- without P2OS never holds its code (compiled functions are live Lua heap, which the collector
-- walks for every plugin: docs/perf-log.md, 7 December 2026). Compiled once at load as well, so
-- that a missing or broken file says so when Wireshark starts.

robot_chunk("p2os_dissect")
local D -- the module once run: D.dissector, D.heuristic, D.init
local function dissection()
    if not D then
        D = robot_chunk("p2os_dissect")({ robot_module = true }, {
            R = robot_chunk("p2os_rules")({ robot_module = true }),
            proto = p2os, pf = pf, ex = ex, config_pf = config_pf, istr = istr, u8 = u8,
            CONFIG_FIELDS = CONFIG_FIELDS, DEGREES_PER_UNIT = DEGREES_PER_UNIT, COMMANDS = COMMANDS,
            SYNC_NAMES = SYNC_NAMES, SERVER_TYPES = SERVER_TYPES, DIRECTION_INFO = DIRECTION_INFO,
            ARG_POSITIVE = ARG_POSITIVE, ARG_NEGATIVE = ARG_NEGATIVE, ARG_STRING = ARG_STRING,
            TYPE_CONFIG = TYPE_CONFIG, TYPE_SIP_STOPPED = TYPE_SIP_STOPPED, TYPE_SIP_MOVING = TYPE_SIP_MOVING,
            TYPE_ENCODER = TYPE_ENCODER,
        })
    end
    return D
end

-- per-capture state: the module's (none before it runs)
function p2os.init()
    if D then D.init() end
end

function p2os.dissector(tvb, pinfo, tree)
    return dissection().dissector(tvb, pinfo, tree)
end

-- heuristic (robots/p2os_dissect.lua); a buffer not starting FA FB is not P2OS without the module
local function heuristic(tvb, pinfo, tree)
    if tvb:len() < 5 or u8(tvb, 0) ~= 0xFA or u8(tvb, 1) ~= 0xFB then
        return false
    end
    return dissection().heuristic(tvb, pinfo, tree)
end

p2os:register_heuristic("tcp", heuristic)
p2os:register_heuristic("udp", heuristic)

local registered_port = 0
local function register_port()
    local tcp_table = DissectorTable.get("tcp.port")
    if registered_port ~= 0 then
        tcp_table:remove(registered_port, p2os)
    end
    registered_port = p2os.prefs.tcp_port
    if registered_port ~= 0 then
        tcp_table:add(registered_port, p2os)
    end
end

function p2os.prefs_changed()
    if registered_port ~= p2os.prefs.tcp_port then
        register_port()
    end
end

register_port()
