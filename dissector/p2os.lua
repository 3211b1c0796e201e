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
-- framing rules it shares with serial.lua; sharedlink plugins install copies both).
-- Twins (code that must exist in two self-contained files; tests/dissector/test_lua_twins.py
-- shows they agree): istr, u8 <-> blackboard.lua.
-- File order (../shared/STYLE.md): header, plugin info, Proto and tables, fields and experts,
-- preferences and state, helpers, dissect_*, the buffer dissector, heuristic, registration.

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
-- for this file and serial.lua: robots/p2os_rules.lua beside this file, loaded here (a copy of
-- our own: no state shared with serial.lua).
local R
do
    local here = (debug.getinfo(1, "S").source or ""):match("^@(.*[/\\])") or ""
    -- (Wireshark's loadfile raises where Lua's returns nil and the reason)
    local ok, chunk, err = pcall(loadfile, here .. "robots/p2os_rules.lua")
    if not ok or not chunk then
        err = tostring(ok and err or chunk)
        error("p2os.lua needs robots/p2os_rules.lua beside it (sharedlink plugins install copies both): " .. err)
    end
    R = chunk({ robot_module = true })
end
local MAX_COUNT = R.MAX_COUNT

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

-- connection state: the frame of the first SYNC2 echo per conversation. Commands 0..2
-- without argument before it are SYNC0..SYNC2, after it PULSE, OPEN, CLOSE.
local sync2_frame = {}
local conversations = 0 -- keys in sync2_frame (bounded by max_conversations)
local not_kept = {} -- frame number -> true: a SYNC2 echo past max_conversations

function p2os.init()
    sync2_frame = {}
    conversations = 0
    not_kept = {}
end

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

-- first FA FB at or after off (both bytes present), or nil
local function find_header(tvb, off, n)
    local i = off
    while i + 1 < n do
        if u8(tvb, i) == 0xFA and u8(tvb, i + 1) == 0xFB then
            return i
        end
        i = i + 1
    end
    return nil
end

-- the P2OS checksum of the payload tvb[off .. off + len - 1] (robots/p2os_rules.lua)
local function checksum_at(tvb, off, len)
    if len == 0 then return 0 end
    return R.checksum(tvb:raw(off, len), 1, len)
end

local function to_signed16(v)
    if v >= 32768 then
        return v - 65536
    end
    return v
end

-- a NUL-terminated string at off (before stop): returns its length (without NUL) and whether
-- the NUL was found
local function cstring_len(tvb, off, stop)
    local i = off
    while i < stop do
        if u8(tvb, i) == 0 then
            return i - off, true
        end
        i = i + 1
    end
    return stop - off, false
end

-- printable text for the Info column and labels: control and non-ASCII bytes as \xNN
local function printable(text)
    return (string.gsub(text, "[%c\128-\255]", function(c)
        return string.format("\\x%02X", string.byte(c))
    end))
end

local function add_string(tree, field, tvb, off, len, nul)
    -- a zero-length string is shown on its NUL byte (never a zero-length range)
    local rlen = len
    if nul then
        rlen = len + 1
    end
    if rlen <= 0 then
        return nil, ""
    end
    local text = ""
    if len > 0 then
        text = printable(tvb:range(off, len):string())
    end
    return tree:add(field, tvb:range(off, rlen), text), text
end

local function conversation_key(pinfo)
    local a = tostring(pinfo.src) .. ":" .. istr(pinfo.src_port)
    local b = tostring(pinfo.dst) .. ":" .. istr(pinfo.dst_port)
    if a < b then
        return a .. "-" .. b
    end
    return b .. "-" .. a
end

-- ---------------------------------------------------------------------------------------------
-- client commands

local function dissect_command(tvb, tree, off, plen, in_handshake)
    local num = u8(tvb, off)
    local name = COMMANDS[num]
    local ci = tree:add(pf.command, tvb:range(off, 1))
    if name == nil then
        name = "command " .. istr(num)
        ci:add_proto_expert_info(ex.unknown_command)
    end
    if SYNC_NAMES[num] and plen == 1 and in_handshake then
        name = SYNC_NAMES[num]
    end
    tree:add(pf.command_name, tvb:range(off, 1), name):set_generated()
    if plen == 1 then
        return name
    end
    local t = u8(tvb, off + 1)
    local ti = tree:add(pf.argtype, tvb:range(off + 1, 1))
    local summary
    local used
    if t == ARG_POSITIVE or t == ARG_NEGATIVE then
        if plen < 4 then
            -- (one summary a problem, issue 41: what is present is in the packet's byte count)
            ti:add_proto_expert_info(ex.arg_truncated, "Integer argument truncated")
            return name .. " (argument truncated)"
        end
        local mag = tvb:range(off + 2, 2):le_uint()
        local v = mag
        if t == ARG_NEGATIVE then
            v = -mag
        end
        tree:add(pf.arg_int, tvb:range(off + 2, 2), v)
        summary = name .. " " .. istr(v)
        used = 4
    elseif t == ARG_STRING then
        if plen < 3 then
            ti:add_proto_expert_info(ex.arg_truncated, "String argument without its length")
            return name .. " (argument truncated)"
        end
        local slen = u8(tvb, off + 2)
        local li = tree:add(pf.arg_length, tvb:range(off + 2, 1))
        local have = plen - 3
        if have < slen then
            -- (its length is p2os.arg.length, what is present p2os.arg.string)
            li:add_proto_expert_info(ex.arg_truncated, "String argument truncated")
            slen = have
        end
        if slen > 0 then
            local _, text = add_string(tree, pf.arg_string, tvb, off + 3, slen, false)
            summary = name .. ' "' .. text .. '"'
        else
            summary = name .. ' ""'
        end
        used = 3 + slen
        -- ARIA (ArRobotPacketSender::comStr: strToBuf) sends the NUL that ends the string after
        -- the counted characters: its terminator, not extra bytes
        if plen > used and u8(tvb, off + used) == 0 then
            tree:add(pf.arg_terminator, tvb:range(off + used, 1))
            used = used + 1
        end
    else
        ti:add_proto_expert_info(ex.arg_unknown)
        if plen > 2 then
            tree:add(pf.arg_data, tvb:range(off + 2, plen - 2))
        end
        return name .. " (unknown argument type)"
    end
    if plen > used then
        tree:add(pf.extra, tvb:range(off + used, plen - used)):add_proto_expert_info(ex.extra)
    end
    return summary
end

-- ---------------------------------------------------------------------------------------------
-- server packets

-- standard SIP layout after the type byte: field, size, signed
local SIP_HEAD = {
    { pf.sip_xpos, 2, "XPOS" }, { pf.sip_ypos, 2, "YPOS" }, { pf.sip_thpos, 2, "THPOS" },
    { pf.sip_lvel, 2, "LVEL" }, { pf.sip_rvel, 2, "RVEL" }, { pf.sip_battery, 1, "BATTERY" },
    { pf.sip_stall, 2, "STALL/BUMPERS" }, { pf.sip_control, 2, "CONTROL" }, { pf.sip_flags, 2, "FLAGS" },
    { pf.sip_compass, 1, "COMPASS" },
}
local SIP_TAIL = {
    { pf.sip_grip, "GRIP_STATE" }, { pf.sip_anport, "ANPORT" }, { pf.sip_analog, "ANALOG" },
    { pf.sip_digin, "DIGIN" }, { pf.sip_digout, "DIGOUT" },
}

local function dissect_sip(tvb, tree, off, plen)
    local t = u8(tvb, off)
    tree:add(pf.sip_moving, tvb:range(off, 1), t == TYPE_SIP_MOVING)
    local stop = off + plen
    local i = off + 1
    local v = {}
    for _, spec in ipairs(SIP_HEAD) do
        local f, size = spec[1], spec[2]
        if i + size > stop then
            tree:add_proto_expert_info(ex.sip_truncated, "Standard SIP truncated")   -- (issue 41: no field name)
            return "SIP (truncated)"
        end
        local r = tvb:range(i, size)
        local item = tree:add_le(f, r)
        v[f] = r:le_uint()
        if f == pf.sip_thpos then
            local deg = to_signed16(v[f]) * DEGREES_PER_UNIT
            item:append_text(string.format(" (%.1f degrees)", deg))
            tree:add(pf.sip_heading, r, deg):set_generated()
        elseif f == pf.sip_battery then
            item:append_text(string.format(" (%.1f V)", v[f] / 10))
            tree:add(pf.sip_volts, r, v[f] / 10):set_generated()
        elseif f == pf.sip_stall then
            item:add_le(pf.sip_stall_left, r)
            item:add_le(pf.sip_stall_right, r)
        elseif f == pf.sip_flags then
            item:add_le(pf.sip_motors, r)
        elseif f == pf.sip_compass then
            item:append_text(" (" .. istr(v[f] * 2) .. " degrees)")
        end
        i = i + size
    end
    local summary = string.format("SIP %s x=%s y=%s th=%.1f v=%s/%s %.1fV",
        (t == TYPE_SIP_MOVING) and "moving" or "stopped",
        istr(v[pf.sip_xpos]), istr(v[pf.sip_ypos]), to_signed16(v[pf.sip_thpos]) * DEGREES_PER_UNIT,
        istr(to_signed16(v[pf.sip_lvel])), istr(to_signed16(v[pf.sip_rvel])), v[pf.sip_battery] / 10)
    if i + 1 > stop then
        tree:add_proto_expert_info(ex.sip_truncated, "Standard SIP truncated before the sonar count")
        return summary .. " (truncated)"
    end
    local nson = u8(tvb, i)
    local st = tree:add(pf.sip_sonar_count, tvb:range(i, 1))
    i = i + 1
    for _ = 1, nson do
        if i + 3 > stop then
            st:add_proto_expert_info(ex.sip_truncated, "Standard SIP truncated in its sonar readings")
            return summary .. " (truncated)"
        end
        local num = u8(tvb, i)
        local rng = tvb:range(i + 1, 2):le_uint()
        local rt = st:add(pf.sip_sonar_range, tvb:range(i, 3), rng)
        rt:set_text("Sonar " .. istr(num) .. ": " .. istr(rng) .. " mm")
        rt:add(pf.sip_sonar_number, tvb:range(i, 1))
        i = i + 3
    end
    for _, spec in ipairs(SIP_TAIL) do
        if i + 1 > stop then
            tree:add_proto_expert_info(ex.sip_truncated, "Standard SIP truncated")
            return summary .. " (truncated)"
        end
        tree:add(spec[1], tvb:range(i, 1))
        i = i + 1
    end
    if stop > i then
        tree:add(pf.sip_extra, tvb:range(i, stop - i))
    end
    return summary
end

local function dissect_sync(tvb, tree, off, plen)
    local num = u8(tvb, off)
    tree:add(pf.sync, tvb:range(off, 1))
    local summary = "SYNC" .. istr(num) .. " echo"
    local i = off + 1
    local stop = off + plen
    local names = { pf.robot_name, pf.robot_class, pf.robot_subclass }
    local texts = {}
    for _, f in ipairs(names) do
        if i >= stop then
            break
        end
        local len, nul = cstring_len(tvb, i, stop)
        local _, text = add_string(tree, f, tvb, i, len, nul)
        texts[#texts + 1] = text
        i = i + len
        if nul then
            i = i + 1
        end
    end
    if stop > i then
        tree:add(pf.extra, tvb:range(i, stop - i)):add_proto_expert_info(ex.extra)
    end
    if #texts > 0 then
        summary = summary .. " " .. table.concat(texts, " ")
    end
    return summary
end

local function dissect_encoder(tvb, tree, off, plen)
    if plen < 9 then
        tree:add_proto_expert_info(ex.sip_truncated, "ENCODER packet truncated")
        return "ENCODER (truncated)"
    end
    local l = tvb:range(off + 1, 4):le_int()
    local r = tvb:range(off + 5, 4):le_int()
    tree:add_le(pf.enc_left, tvb:range(off + 1, 4))
    tree:add_le(pf.enc_right, tvb:range(off + 5, 4))
    if plen > 9 then
        tree:add(pf.extra, tvb:range(off + 9, plen - 9)):add_proto_expert_info(ex.extra)
    end
    return "ENCODER " .. istr(l) .. "/" .. istr(r)
end

local function dissect_config(tvb, tree, off, plen)
    local i = off + 1
    local stop = off + plen
    local summary = "CONFIG"
    for _, c in ipairs(CONFIG_FIELDS) do
        if i >= stop then
            break
        end
        local f = config_pf[c[1]]
        if c[2] == "s" then
            local len, nul = cstring_len(tvb, i, stop)
            if not nul then
                break
            end
            local _, text = add_string(tree, f, tvb, i, len, nul)
            if c[1] == "name" then
                summary = summary .. " " .. text
            end
            i = i + len + 1
        else
            if i + c[2] > stop then
                break
            end
            tree:add_le(f, tvb:range(i, c[2]))
            i = i + c[2]
        end
    end
    if stop > i then
        tree:add(pf.config_extra, tvb:range(i, stop - i))
    end
    return summary
end

local function dissect_server(tvb, tree, off, plen)
    local t = u8(tvb, off)
    local ti = tree:add(pf.type, tvb:range(off, 1))
    if t == TYPE_SIP_STOPPED or t == TYPE_SIP_MOVING then
        return dissect_sip(tvb, tree, off, plen)
    elseif t <= 2 then
        return dissect_sync(tvb, tree, off, plen)
    elseif t == TYPE_ENCODER then
        return dissect_encoder(tvb, tree, off, plen)
    elseif t == TYPE_CONFIG then
        return dissect_config(tvb, tree, off, plen)
    end
    ti:add_proto_expert_info(ex.unknown_type)
    if plen > 1 then
        tree:add(pf.data, tvb:range(off + 1, plen - 1))
    end
    return (SERVER_TYPES[t] or "type 0x" .. string.format("%02X", t)) .. " (not decoded)"
end

-- ---------------------------------------------------------------------------------------------
-- direction: by port, by the capture's direction flag, else from the content

local function direction(pinfo, tvb, off, plen)
    local port = p2os.prefs.tcp_port
    if port ~= 0 then
        if pinfo.dst_port == port then
            return true, "the server's TCP port"
        elseif pinfo.src_port == port then
            return false, "the server's TCP port"
        end
    end
    local d = pinfo.p2p_dir
    if d == 0 then
        return true, "the capture (sent by the client's side)"
    elseif d == 1 then
        return false, "the capture (received by the client's side)"
    end
    return plen < 1 or R.from_client(tvb:raw(off, plen), 1, plen), nil
end

-- ---------------------------------------------------------------------------------------------
-- one packet (header at h, count bytes after the count byte, all present in tvb)

-- a SYNC2 echo (with the robot's strings): the conversation's handshake ends here, unless
-- max_conversations conversations are remembered already
local function note_sync2(pinfo, tree, key)
    if not pinfo.visited then
        local s2 = sync2_frame[key]
        if s2 == nil and conversations >= p2os.prefs.max_conversations then
            not_kept[pinfo.number] = true
        elseif s2 == nil or pinfo.number < s2 then
            conversations = conversations + (s2 == nil and 1 or 0)
            sync2_frame[key] = pinfo.number
        end
    end
    if not_kept[pinfo.number] then
        tree:add_proto_expert_info(ex.limit, "Limit exceeded: " .. istr(p2os.prefs.max_conversations)
            .. " conversations remembered (p2os.max_conversations); this one's handshake is not")
    end
end

-- link health (issue 43 on P2OS links): the robot's packets, its SIPs the heartbeat, go to
-- SharedLink's health module when sharedlink.lua is loaded (the definition is written once there:
-- dissector/sharedlink/health.lua, H.robot); the first packet after an outage gets the expert
-- p2os.outage and the generated p2os.outage.duration.  Without sharedlink.lua: nothing.
local function link_health(pinfo, pt, where, status)
    local health = package.loaded["sharedlink.health"]
    if type(health) ~= "table" or not health.robot then return end
    local gone = health.robot(pinfo, where, "p2os", "robot", status)
    if gone then health.mark(pt, nil, gone, pf.outage_duration, ex.outage) end
end

local function dissect_one(tvb, pinfo, tree, h, count)
    local total = 3 + count
    local pt = tree:add(p2os, tvb:range(h, total))
    pt:add(pf.header, tvb:range(h, 2))
    local ci = pt:add(pf.count, tvb:range(h + 2, 1))
    local plen = count - 2
    local off = h + 3
    local calc = checksum_at(tvb, off, plen)
    local crange = tvb:range(off + plen, 2)
    local written = crange:uint()
    local client, how = direction(pinfo, tvb, off, plen)
    -- the robot ignores a client command over 200 bytes (the P2OS manual); a server packet may
    -- count up to 255 (ARIA reads them; shared/PROTOCOL-NOTES.md, issue 40): no expert for it
    local too_big = client and count > MAX_COUNT
    if too_big then
        ci:add_proto_expert_info(ex.count_big)
    end
    local di = pt:add(pf.direction, tvb:range(h, total), client and 0 or 1)
    di:set_generated()
    if how then
        di:append_text(", from " .. how)
    else
        di:append_text(", guessed from the content")
        di:add_proto_expert_info(ex.direction_guess)
    end
    local summary
    if plen == 0 then
        pt:add_proto_expert_info(ex.empty)
        summary = "empty packet"
    else
        local body = pt:add(pf.payload, tvb:range(off, plen))
        local key = conversation_key(pinfo)
        if client then
            local s2 = sync2_frame[key]
            summary = dissect_command(tvb, body, off, plen, s2 == nil or pinfo.number <= s2)
        else
            if plen > 1 and u8(tvb, off) == 2 then
                note_sync2(pinfo, body, key)
            end
            summary = dissect_server(tvb, body, off, plen)
        end
    end
    local ck = pt:add(pf.checksum, crange)
    pt:add(pf.checksum_calc, crange, calc):set_generated()
    local status
    if written == calc then
        ck:append_text(" [correct]")
        status = 1
    else
        ck:append_text(" [incorrect, should be 0x" .. string.format("%04X", calc) .. "]")
        -- one summary a problem (issue 41): the values are p2os.checksum and p2os.checksum.calculated
        ck:add_proto_expert_info(ex.checksum_bad)
        status = 0
        summary = summary .. " [bad checksum]"
    end
    pt:add(pf.checksum_status, crange, status):set_generated()
    if not client then
        link_health(pinfo, pt, h .. "/" .. tvb:len(), status)
    end
    if too_big then
        summary = summary .. " [count > 200]"
    end
    pt:append_text(", " .. (client and "client to robot: " or "robot to client: ") .. summary)
    return summary, client and 0 or 1
end

-- "Client→Robot SYNC0; SYNC1; Robot→Client SYNC0 echo": the direction said when it changes;
-- past 6 entries the first 3 and the count
local function info_text(infos, dirs)
    local parts, last = {}, nil
    local shown = #infos > 6 and 3 or #infos
    for i = 1, shown do
        local d = dirs[i]
        parts[i] = ((d ~= nil and d ~= last) and DIRECTION_INFO[d] or "") .. infos[i]
        if d ~= nil then last = d end
    end
    if shown < #infos then parts[#parts + 1] = "... (" .. istr(#infos) .. " packets)" end
    return table.concat(parts, "; ")
end

-- a header cut off before a packet at h (R.resync_at over s, the buffer's bytes): junk up to
-- the packet, and where to go on; "more" after asking TCP for more bytes; nil when h is no such
-- header
local function skip_cut_header(tvb, s, pinfo, tree, h, can_more, infos)
    if h + 3 > #s or u8(tvb, h + 2) < 2 then return nil end
    local k = R.resync_at(s, h + 1, not can_more)
    if k and k ~= "wait" then k = k - 1 end
    if k == "wait" then
        pinfo.desegment_offset = h
        pinfo.desegment_len = DESEGMENT_ONE_MORE_SEGMENT
        return "more"
    elseif k then
        tree:add(pf.junk, tvb:range(h, k - h)):add_proto_expert_info(ex.junk)
        infos[#infos + 1] = "junk"
    end
    return k
end

-- whole buffer: packets and the bytes between them. Returns bytes consumed, or the buffer
-- length after asking TCP for more.
local function dissect_buffer(tvb, pinfo, tree)
    local n = tvb:len()
    if n == 0 then
        return 0
    end
    pinfo.cols.protocol = "P2OS"
    local can_more = pinfo.can_desegment > 0
    local s = tvb:raw(0, n)
    local infos = {}
    local dirs = {} -- infos[i]'s direction (0 client to robot, 1 robot to client), if a packet
    local off = 0
    while off < n do
        local h = find_header(tvb, off, n)
        if h == nil then
            local stop = n
            if can_more and u8(tvb, n - 1) == 0xFA then
                stop = n - 1 -- maybe the start of a header
            end
            if stop > off then
                tree:add(pf.junk, tvb:range(off, stop - off)):add_proto_expert_info(ex.junk)
                infos[#infos + 1] = "junk"
            end
            if stop < n then
                pinfo.desegment_offset = stop
                pinfo.desegment_len = DESEGMENT_ONE_MORE_SEGMENT
            end
            break
        end
        if h > off then
            tree:add(pf.junk, tvb:range(off, h - off)):add_proto_expert_info(ex.junk)
            infos[#infos + 1] = "junk"
        end
        local k = skip_cut_header(tvb, s, pinfo, tree, h, can_more, infos)
        if k == "more" then
            break
        elseif k then
            off = k
        elseif h + 3 > n or h + 3 + u8(tvb, h + 2) > n then
            if can_more then
                -- one more segment, not the bytes the count claims: the count may be a cut-off
                -- header's, and the next segment may bring the FA FB it resynchronises on
                -- (R.resync_at; asking for the claimed bytes would wait for bytes that never come)
                pinfo.desegment_offset = h
                pinfo.desegment_len = DESEGMENT_ONE_MORE_SEGMENT
                break
            end
            local t = tree:add(p2os, tvb:range(h, n - h))
            t:append_text(", truncated")
            t:add(pf.header, tvb:range(h, 2))
            if h + 3 <= n then
                t:add(pf.count, tvb:range(h + 2, 1))
            end
            t:add_proto_expert_info(ex.truncated)   -- (its byte count: p2os.count)
            infos[#infos + 1] = "truncated packet"
            break
        elseif u8(tvb, h + 2) < 2 then
            local t = tree:add(p2os, tvb:range(h, 3))
            t:add(pf.header, tvb:range(h, 2))
            t:add(pf.count, tvb:range(h + 2, 1)):add_proto_expert_info(ex.count_small)
            infos[#infos + 1] = "bad count"
            off = h + 3
        else
            local count = u8(tvb, h + 2)
            infos[#infos + 1], dirs[#infos + 1] = dissect_one(tvb, pinfo, tree, h, count)
            off = h + 3 + count
        end
    end
    if #infos > 0 then
        pinfo.cols.info = info_text(infos, dirs)
    end
    return n
end

function p2os.dissector(tvb, pinfo, tree)
    return dissect_buffer(tvb, pinfo, tree)
end

-- heuristic: FA FB, a count of 2..255 (server packets run to 255), the whole first packet
-- present with a good checksum
local function heuristic(tvb, pinfo, tree)
    local n = tvb:len()
    if n < 5 or u8(tvb, 0) ~= 0xFA or u8(tvb, 1) ~= 0xFB then
        return false
    end
    local count = u8(tvb, 2)
    if count < 2 or 3 + count > n then
        return false
    end
    local plen = count - 2
    if checksum_at(tvb, 3, plen) ~= tvb:range(3 + plen, 2):uint() then
        return false
    end
    dissect_buffer(tvb, pinfo, tree)
    -- the rest of this conversation comes straight here (where the version allows)
    pcall(function()
        pinfo.conversation = p2os
    end)
    return true
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
