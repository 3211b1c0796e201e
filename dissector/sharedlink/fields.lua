-- SharedLink dissector module: fields and experts, the keyed tables hf and ei (registered by the
-- entry, sharedlink.lua, with register).  Loaded by sharedlink.lua (load_module); Wireshark also runs
-- every .lua file of a plugin folder's subfolders as a plugin of its own: this file then does nothing.

local token = ...
if type(token) ~= "table" or token.sharedlink_module ~= true then return end

-- 1 and 3 are not defined by the bulletins: Wireshark shows them as "Unknown (n)"
local type_names = { [0] = "long", [2] = "double", [4] = "string" }
local checksum_status_vals = { [0] = "Bad", [1] = "Good", [2] = "Unverified" }

local hf = {
    dst = ProtoField.string("sharedlink.dst", "Destination"),
    src = ProtoField.string("sharedlink.src", "Source"),
    dst_node = ProtoField.uint8("sharedlink.dst.node", "Destination node", base.DEC),
    src_node = ProtoField.uint8("sharedlink.src.node", "Source node", base.DEC),
    kind = ProtoField.string("sharedlink.kind", "Frame kind"),
    ordinal = ProtoField.uint32("sharedlink.ordinal", "Start ordinal (N)", base.DEC),
    inbound_ordinal = ProtoField.uint32("sharedlink.inbound_ordinal", "Inbound list ordinal (L)", base.DEC),
    ftype = ProtoField.uint8("sharedlink.type", "Type (T)", base.DEC, type_names),
    query = ProtoField.string("sharedlink.query", "Query (Q)"),
    response = ProtoField.string("sharedlink.response", "Reply (R)"),
    var = ProtoField.none("sharedlink.var", "Variable"),
    var_name = ProtoField.string("sharedlink.var.name", "Name"),
    var_index = ProtoField.uint32("sharedlink.var.index", "Index", base.DEC),
    var_value = ProtoField.string("sharedlink.var.value", "Value"),
    var_double = ProtoField.double("sharedlink.var.double", "Double value"),
    var_long = ProtoField.int64("sharedlink.var.long", "Long value", base.DEC),
    var_string = ProtoField.string("sharedlink.var.string", "String value"),
    var_carried = ProtoField.bool("sharedlink.var.carried", "Carried forward"),
    var_carried_from = ProtoField.framenum("sharedlink.var.carried_from", "Value from frame", base.NONE),
    checksum = ProtoField.uint8("sharedlink.checksum", "Checksum", base.HEX),
    checksum_text = ProtoField.string("sharedlink.checksum.text", "Checksum text"),
    checksum_calc = ProtoField.uint8("sharedlink.checksum.calculated", "Calculated checksum", base.HEX),
    checksum_status = ProtoField.uint8("sharedlink.checksum.status", "Checksum status", base.DEC,
        checksum_status_vals),
    response_in = ProtoField.framenum("sharedlink.response_in", "Response in", base.NONE, frametype.RESPONSE),
    response_to = ProtoField.framenum("sharedlink.response_to", "Response to", base.NONE, frametype.REQUEST),
    response_time = ProtoField.relative_time("sharedlink.response_time", "Response time"),
    command = ProtoField.string("sharedlink.command", "Command (E)"),
    command_arg = ProtoField.string("sharedlink.command.arg", "Command argument"),
    mode = ProtoField.string("sharedlink.mode", "Mode (M)"),
    ping = ProtoField.string("sharedlink.ping", "Ping (P)"),
    pong = ProtoField.string("sharedlink.pong", "Pong (G)"),
    field_letter = ProtoField.string("sharedlink.field.letter", "Unknown field letter"),
    field_text = ProtoField.string("sharedlink.field.text", "Unknown field text"),
    noise = ProtoField.bytes("sharedlink.noise", "Noise"),
    -- the sync.late condition as a field (the expert of the same name cannot be read by a tap)
    sync_is_late = ProtoField.bool("sharedlink.sync.is_late", "Sync late"),
    -- a late frame's time since its direction's last full frame (the sync.late expert's value)
    sync_gap = ProtoField.relative_time("sharedlink.sync.gap", "Time since the last full frame"),
}
-- fields and experts are registered by a loop over their keyed tables, in key order
-- (a stable order for tshark -G fields)
local function register(tbl)
    local keys = {}
    for k in pairs(tbl) do keys[#keys + 1] = k end
    table.sort(keys)
    local list = {}
    for i, k in ipairs(keys) do list[i] = tbl[k] end
    return list
end
local ei = {
    checksum_bad = ProtoExpert.new("sharedlink.checksum.bad", "Bad checksum",
        expert.group.CHECKSUM, expert.severity.ERROR),
    checksum_format = ProtoExpert.new("sharedlink.checksum.format",
        "Checksum is not two upper-case hex digits", expert.group.PROTOCOL, expert.severity.NOTE),
    checksum_missing = ProtoExpert.new("sharedlink.checksum.missing", "No checksum field",
        expert.group.PROTOCOL, expert.severity.WARN),
    address_invalid = ProtoExpert.new("sharedlink.address.invalid", "Address is not a letter A-P",
        expert.group.PROTOCOL, expert.severity.WARN),
    field_unknown = ProtoExpert.new("sharedlink.field.unknown", "Unknown field letter",
        expert.group.UNDECODED, expert.severity.NOTE),
    field_empty = ProtoExpert.new("sharedlink.field.empty", "Empty field",
        expert.group.PROTOCOL, expert.severity.NOTE),
    malformed = ProtoExpert.new("sharedlink.malformed", "Malformed frame",
        expert.group.MALFORMED, expert.severity.ERROR),
    sync_late = ProtoExpert.new("sharedlink.sync.late", "No full frame within the sync interval",
        expert.group.SEQUENCE, expert.severity.WARN),
    var_unknown = ProtoExpert.new("sharedlink.var.unknown", "Positional value past the known variable list",
        expert.group.PROTOCOL, expert.severity.WARN),
    var_badvalue = ProtoExpert.new("sharedlink.var.badvalue", "Value does not match its declared type",
        expert.group.PROTOCOL, expert.severity.WARN),
    crlf_missing = ProtoExpert.new("sharedlink.crlf.missing", "Frame not terminated by CR LF",
        expert.group.PROTOCOL, expert.severity.NOTE),
    noise = ProtoExpert.new("sharedlink.noise.skipped", "Bytes outside any frame",
        expert.group.PROTOCOL, expert.severity.NOTE),
    unanswered = ProtoExpert.new("sharedlink.reply.unmatched", "Reply without a matching query",
        expert.group.SEQUENCE, expert.severity.NOTE),
    -- input past one of the limits (docs/fields-sharedlink.md "Limits"): dropped, never allocated
    limit = ProtoExpert.new("sharedlink.limit.exceeded", "Limit exceeded",
        expert.group.PROTOCOL, expert.severity.WARN),
}

return { hf = hf, ei = ei, register = register }
