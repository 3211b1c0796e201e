-- SharedLink dissector module: prefs, the preferences and the values in use (cfg, read again by
-- cfg.read at init and when the preferences change).  Loaded by sharedlink.lua (load_module);
-- Wireshark also runs every .lua file of a plugin folder's subfolders as a plugin of its own: this
-- file then does nothing.

local token, M = ...
if type(token) ~= "table" or token.sharedlink_module ~= true then return end

local sl, U = M.proto, M.util

local DEFAULT_PORTS = "7013"
local DEFAULT_VARS = "AutoGpsLat,AutoGpsLon,AutoGpsHead,AutoGpsVel"

sl.prefs.ports = Pref.range("UDP/TCP ports", DEFAULT_PORTS,
    "Ports always decoded as SharedLink (UDP and TCP)", 65535)
sl.prefs.heuristic = Pref.bool("Try heuristic on other ports", true,
    "Look for SharedLink frames on any UDP/TCP port")
sl.prefs.validate_checksum = Pref.bool("Validate the checksum", true,
    "Compute and compare the frame checksum")
sl.prefs.variables = Pref.string("Positional variable list", DEFAULT_VARS,
    "Comma-separated a-priori variable list naming positional D values (index 0 first)")
sl.prefs.sync_interval = Pref.uint("Sync interval (ms)", 1000,
    "A full frame is expected at least this often per direction (plus 500 ms slack)")
-- Limits (issue 31; the same names and defaults as the Python tools' sharedlink.protocols.limits)
local LIMIT_DEFAULTS = { max_slots = 1024, max_names = 4096, max_conversations = 65536, max_pending = 1024,
    max_held_bytes = 65536 }
sl.prefs.max_slots = Pref.uint("Maximum slot number", LIMIT_DEFAULTS.max_slots,
    "Positional slots, ordinals and declared list entries at or past this number are dropped")
sl.prefs.max_names = Pref.uint("Maximum names a direction holds", LIMIT_DEFAULTS.max_names,
    "New variable names past this many in one direction are dropped")
sl.prefs.max_conversations = Pref.uint("Maximum directions with state", LIMIT_DEFAULTS.max_conversations,
    "Directions past this many keep no state")
sl.prefs.max_pending = Pref.uint("Maximum unanswered queries", LIMIT_DEFAULTS.max_pending,
    "Queries past this many unanswered ones in a conversation are not matched with a reply")
sl.prefs.max_held_bytes = Pref.uint("Maximum bytes held for an unterminated frame", LIMIT_DEFAULTS.max_held_bytes,
    "A TCP frame not terminated within this many bytes is decoded as unterminated")

-- "Name:T,Name,..." -> list of names with list.t[i] = type number (0 long, 2 double,
-- 4 string) for the typed ones (twin: pytools sharedlink --variables parser)
local function parse_list(str)
    local list, types = {}, {}
    list.t = types
    if type(str) ~= "string" then return list end
    for item in str:gmatch("[^,]+") do
        local name = item:match("^%s*(.-)%s*$")
        local n, t = name:match("^(.-)%s*:%s*(%d+)$")
        if n and n ~= "" then name = n end
        if name ~= "" then
            list[#list + 1] = name
            if n and n ~= "" then types[#list] = tonumber(t) end
        end
    end
    return list
end

-- The values in use: list (the parsed variable list), validate, heuristic, sync (the interval plus
-- the slack, in seconds), and LIM: the limits and the per-capture facts they need: journal (a
-- direction keeps a journal, see state's journal), ndirs (directions with state), npend
-- (unanswered queries a conversation), hit (the current frame's limit text, else false)
local cfg = { list = parse_list(DEFAULT_VARS), validate = true, heuristic = true, sync = 1.0 + U.SYNC_SLACK,
    LIM = { journal = false, ndirs = 0, npend = {}, hit = false } }

local function read_limits()
    local LIM = cfg.LIM
    for k, v in pairs(LIMIT_DEFAULTS) do
        local x = tonumber(sl.prefs[k])
        LIM[k] = (x and x >= 0) and math.floor(x) or v
    end
end
read_limits()

-- the preferences' values (at init and when they change)
function cfg.read()
    cfg.list = parse_list(sl.prefs.variables)
    cfg.validate = sl.prefs.validate_checksum
    cfg.heuristic = sl.prefs.heuristic
    cfg.sync = (tonumber(sl.prefs.sync_interval) or 1000) / 1000 + U.SYNC_SLACK
    read_limits()
end

-- the per-capture facts the limits keep (init)
function cfg.reset()
    local LIM = cfg.LIM
    LIM.journal, LIM.ndirs, LIM.npend, LIM.hit = false, 0, {}, false
end

return cfg
