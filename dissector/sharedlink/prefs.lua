-- SharedLink dissector module: prefs, the preferences and the values in use (cfg, read again by
-- cfg.read at init and when the preferences change).  Loaded by sharedlink.lua (load_module);
-- Wireshark also runs every .lua file of a plugin folder's subfolders as a plugin of its own: this
-- file then does nothing.

local token, M = ...
if type(token) ~= "table" or token.sharedlink_module ~= true then return end

local sl, U = M.proto, M.util

local DEFAULT_PORTS = "7013"
-- the beacon's four values, typed double as BUL-009 declares them (T2), as the Python tools'
-- default (sharedlink.protocols.state.BEACON_VARIABLES)
local DEFAULT_VARS = "AutoGpsLat:2,AutoGpsLon:2,AutoGpsHead:2,AutoGpsVel:2"

sl.prefs.ports = Pref.range("UDP/TCP ports", DEFAULT_PORTS,
    "Ports always decoded as SharedLink (UDP and TCP)", 65535)
sl.prefs.heuristic = Pref.bool("Try heuristic on other ports", true,
    "Look for SharedLink frames on any UDP/TCP port")
sl.prefs.validate_checksum = Pref.bool("Validate the checksum", true,
    "Compute and compare the frame checksum")
sl.prefs.variables = Pref.string("Positional variable list", DEFAULT_VARS,
    "NAME[:TYPE],... (types 0 long, 2 double, 4 string): names a positional frame of as many slots; " ..
    "SRC>DST: NAME[:TYPE],...; ... gives a list for a node pair (as `sharedlink lists` prints it)")
-- The sync interval, named with its unit (issue 41: the CLI's --sync-interval is in seconds, this
-- is in milliseconds).  sharedlink.sync_interval, its old name, still works for one release
-- (wslua has no obsolete-preference alias): a value set there is used when sync_interval_ms is
-- left at its default, with a deprecation note on stderr once.
local SYNC_DEFAULT_MS = 1000
sl.prefs.sync_interval_ms = Pref.uint("Sync interval (ms)", SYNC_DEFAULT_MS,
    "A full frame is expected at least this often per direction, in milliseconds (plus 500 ms slack; " ..
    "the command line's --sync-interval is the same in seconds)")
sl.prefs.sync_interval = Pref.uint("Sync interval (ms), old name (deprecated)", SYNC_DEFAULT_MS,
    "Deprecated: use sharedlink.sync_interval_ms (same value, in ms); used only while that one is at its default")
-- Limits (issue 31; the same names and defaults as the Python tools' sharedlink.protocols.limits)
local LIMIT_DEFAULTS = { max_slots = 1024, max_names = 4096, max_conversations = 65536, max_pending = 1024,
    max_pending_total = 65536, max_held_bytes = 65536 }
sl.prefs.max_slots = Pref.uint("Maximum slot number", LIMIT_DEFAULTS.max_slots,
    "Positional slots, ordinals and declared list entries at or past this number are dropped")
sl.prefs.max_names = Pref.uint("Maximum names a direction holds", LIMIT_DEFAULTS.max_names,
    "New variable names past this many in one direction are dropped")
sl.prefs.max_conversations = Pref.uint("Maximum directions with state", LIMIT_DEFAULTS.max_conversations,
    "Directions past this many keep no state")
sl.prefs.max_pending = Pref.uint("Maximum unanswered queries", LIMIT_DEFAULTS.max_pending,
    "Queries past this many unanswered ones in a conversation are not matched with a reply")
sl.prefs.max_pending_total = Pref.uint("Maximum unanswered queries in all", LIMIT_DEFAULTS.max_pending_total,
    "Queries past this many unanswered ones in all conversations together are not matched with a reply")
sl.prefs.max_held_bytes = Pref.uint("Maximum bytes held for an unterminated frame", LIMIT_DEFAULTS.max_held_bytes,
    "A TCP frame not terminated within this many bytes is decoded as unterminated")

-- The variables preference (docs/fields-sharedlink.md, "Rules for real sessions"; twin:
-- pytools sharedlink.protocols.varlists.parse_varlists, the same rules and messages).  Entries
-- separated by ';' or new lines, each "SRC>DST: NAME[:TYPE],..." (a list for that node pair) or
-- "NAME[:TYPE],..." (the a-priori list of every pair); a line starting with '#' is a comment; a
-- later entry for a pair replaces the earlier one.  A list: names with list.t[i] = type number
-- (0 long, 2 double, 4 string) for the typed ones.  Returns the lists by pair ("*": every pair,
-- else the letters SRC .. DST), or nil and a one-line reason.
local ANY_PAIR = "*"
local VAR_TYPES = { ["0"] = 0, ["2"] = 2, ["4"] = 4 }
local MAX_LIST = 1024   -- Python's MAX_SLOTS (issue 31), fixed: the preference is read before the limits

local function strip(x) return (x:gsub("^%s+", ""):gsub("%s+$", "")) end

local function parse_list(text, where)
    local at = where and (" in " .. where) or ""
    local list, types = {}, {}
    list.t = types
    for item in (text .. ","):gmatch("([^,]*),") do
        item = strip(item)
        if item ~= "" then
            local name, type_text = item, ""
            local c = item:find(":", 1, true)
            if c then name, type_text = strip(item:sub(1, c - 1)), strip(item:sub(c + 1)) end
            if name == "" or name:find("[|%[%],;:>]") then
                return nil, "bad variable name '" .. name .. "'" .. at
            end
            list[#list + 1] = name
            if type_text ~= "" then
                local tc = VAR_TYPES[type_text] or VAR_TYPES[tostring(tonumber(type_text))]
                if not tc or not type_text:match("^[+-]?%d+$") then
                    return nil, "bad type '" .. type_text .. "' for " .. name .. at ..
                        " (types are 0 long, 2 double, 4 string)"
                end
                types[#list] = tc
            end
            if #list > MAX_LIST then return nil, "more than " .. MAX_LIST .. " variables" .. at end
        end
    end
    if #list == 0 then return nil, "empty variable list" .. at end
    return list
end

local function parse_varlists(text)
    local out, any = {}, false
    if type(text) ~= "string" then text = "" end
    for line in (text .. "\n"):gmatch("([^\r\n]*)\r?\n?") do
        if not line:match("^%s*#") then
            for entry in (line .. ";"):gmatch("([^;]*);") do
                if entry:match("%S") then
                    local c = entry:find(":", 1, true)
                    local head = c and entry:sub(1, c - 1)
                    if head and head:find(">", 1, true) then
                        local src, dst = head:match("^%s*([A-P])%s*>%s*([A-P])%s*$")
                        if not src then
                            return nil, "bad node pair '" .. strip(head) .. "' (SRC>DST, letters A-P)"
                        end
                        local list, err = parse_list(entry:sub(c + 1), src .. ">" .. dst)
                        if not list then return nil, err end
                        out[src .. dst] = list
                    else
                        local list, err = parse_list(entry)
                        if not list then return nil, err end
                        out[ANY_PAIR] = list
                    end
                    any = true
                end
            end
        end
    end
    if not any then return nil, "empty variable list" end
    return out
end

-- The lists in use from the preference's text: cfg.list (the a-priori list of every pair, marked
-- by_length: it names only a frame with as many slots as it has; an empty list when there is
-- none) and cfg.pairs (letters SRC .. DST -> the user's list for that pair).  A text that cannot
-- be read gives no list at all (every slot #i) and its reason in cfg.vars_error.
local EMPTY = { t = {} }
local function read_lists(cfg, text)
    local lists, err = parse_varlists(text)
    if err == "empty variable list" then err = nil end   -- an empty preference: no list at all
    cfg.vars_error = err
    lists = lists or {}
    local every = lists[ANY_PAIR]
    if every then every.by_length = true end
    lists[ANY_PAIR] = nil
    cfg.list, cfg.pairs = every or EMPTY, lists
end

-- The values in use: list (the parsed variable list), validate, heuristic, sync (the interval plus
-- the slack, in seconds), and LIM: the limits and the per-capture facts they need: journal (a
-- direction keeps a journal, see state's journal), ndirs (directions with state), npend
-- (unanswered queries a querier), nqueriers (queriers with an entry in npend), npend_total (in all)
local cfg = { list = EMPTY, pairs = {}, validate = true, heuristic = true, sync = 1.0 + U.SYNC_SLACK,
    LIM = { journal = false, ndirs = 0, npend = {}, nqueriers = 0, npend_total = 0 } }

local function read_limits()
    local LIM = cfg.LIM
    for k, v in pairs(LIMIT_DEFAULTS) do
        local x = tonumber(sl.prefs[k])
        LIM[k] = (x and x >= 0) and math.floor(x) or v
    end
end
read_limits()
read_lists(cfg, DEFAULT_VARS)
cfg.parse_varlists = parse_varlists

-- The per-variable value fields sharedlink.value.<name> (docs/fields-sharedlink.md, "Filtering
-- by variable"), registered at load (fields cannot be added later): the names of the Kairos
-- bulletins (BUL-009's beacon, BUL-110's teleop session as the public shared_link_bridge declares
-- it) and of the variables preference (its default and the value saved in the preferences file).
-- A field's type: the preference's type for the name, else the bulletin's, else double (an
-- untyped value is added when it reads as a number).
local KAIROS_NAMES = "AutoGpsLat:2,AutoGpsLon:2,AutoGpsHead:2,AutoGpsVel:2," ..
    "AutoGpsReferences:0,AutoGpsQuality:0,AutoGpsStamp:2,pause:0,key_on:0,eng_enb:0,pe7:0,bbrake:0,fbrake:0," ..
    "steerang:2,throttle:0,svp_enb_eng:0,serialpck:0,veh_gear:0,veh_state:0,veh_estop:0,veh_obstacle:0," ..
    "vehicle_bat:2,run_composite:4,VehicleName:4,Health_total:0,rpm:0,fuel:0,sys_thd:2," ..
    "video_mux1:0,veh_start:0,veh_enable:0,veh_motion:0,joy_steer:2,veh_steer:0,veh_brake:0,veh_throttle:0," ..
    "veh_shift:0,veh_clutch:0"
local MAX_VALUE_FIELDS = 256

-- The variables preference as saved in the preferences file (nil: none saved, or no file).
local function saved_variables()
    if not (Dir and Dir.personal_config_path) then return nil end
    local ok, path = pcall(Dir.personal_config_path, "preferences")
    if not ok or type(path) ~= "string" then return nil end
    local fh = io.open(path, "r")
    if not fh then return nil end
    local text = nil
    for line in fh:lines() do
        local v = line:match("^sharedlink%.variables:%s*(.-)%s*$")
        if v then text = v:match('^"(.*)"$') or v end
    end
    fh:close()
    return text
end

local function value_fields()
    local hf, VALUE, n = M.fields.hf, {}, 0
    local by_type, order = {}, {}
    local function take(text, override)
        local lists = parse_varlists(text or "")
        for _, list in pairs(lists or {}) do
            for k, name in ipairs(list) do
                if by_type[name] == nil then order[#order + 1] = name end
                if by_type[name] == nil or (override and list.t[k]) then by_type[name] = list.t[k] or false end
            end
        end
    end
    take(KAIROS_NAMES, false)
    take(DEFAULT_VARS, true)
    take(saved_variables(), true)
    local MAKE = { [0] = ProtoField.int64, [2] = ProtoField.double, [4] = ProtoField.string }
    for _, name in ipairs(order) do
        if n < MAX_VALUE_FIELDS and name:match("^[%w_%-]+$") then
            local vtype = by_type[name] or 2
            local abbrev = "sharedlink.value." .. name
            local field = vtype == 0 and MAKE[0](abbrev, name, base.DEC) or MAKE[vtype](abbrev, name)
            hf["value:" .. name] = field
            VALUE[name] = { field = field, vtype = vtype }
            n = n + 1
        end
    end
    return VALUE
end
-- name -> { field, vtype } (0 long, 2 double, 4 string)
cfg.VALUE = value_fields()

-- The sync interval in ms: sync_interval_ms, else the old name's value when only that one was set
-- (noted once on stderr as deprecated).
local old_noted = false
function cfg.sync_ms()
    local ms = tonumber(sl.prefs.sync_interval_ms) or SYNC_DEFAULT_MS
    local old = tonumber(sl.prefs.sync_interval) or SYNC_DEFAULT_MS
    if ms == SYNC_DEFAULT_MS and old ~= SYNC_DEFAULT_MS then
        if not old_noted then
            old_noted = true
            io.stderr:write("SharedLink: the preference sharedlink.sync_interval is deprecated: " ..
                "use sharedlink.sync_interval_ms (the same value, in ms)\n")
        end
        return old
    end
    return ms
end

-- the preferences' values (at init and when they change)
function cfg.read()
    local text = sl.prefs.variables
    if text ~= cfg.vars_text then
        cfg.vars_text = text
        read_lists(cfg, text)
        if cfg.vars_error then
            report_failure("SharedLink: the variables preference is not used: " .. cfg.vars_error)
        end
    end
    cfg.validate = sl.prefs.validate_checksum
    cfg.heuristic = sl.prefs.heuristic
    cfg.sync = cfg.sync_ms() / 1000 + U.SYNC_SLACK
    read_limits()
end

-- the per-capture facts the limits keep (init)
function cfg.reset()
    local LIM = cfg.LIM
    LIM.journal, LIM.ndirs, LIM.npend, LIM.nqueriers, LIM.npend_total = false, 0, {}, 0, 0
end

return cfg
