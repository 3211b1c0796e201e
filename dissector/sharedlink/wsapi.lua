-- SharedLink dissector module: wsapi, every use of Wireshark's internals (see the note below).
-- Loaded by sharedlink.lua (load_module); Wireshark also runs every .lua file it finds in a
-- plugin folder's subfolders as a plugin of its own (4.0 with no arguments, 4.4 and later with
-- the file's name and path): this file then does nothing.

local token = ...
if type(token) ~= "table" or token.sharedlink_module ~= true then return end

local s_find = string.find

-- wsapi: every use of Wireshark's internals, in one place.  Each trick is checked once (at load,
-- or on the first packet where it needs an object) against the documented wslua API, and falls
-- back to that API when the check fails; nothing else in this file reaches past the documented
-- API.  The environment switches the tests use are read here too (docs/architecture.md).
local wsapi = { ready = false }
local function documented(name) return function(o) return o[name] end end

-- (1) Pinfo's and TreeItem's attributes read through their getters, the C functions wslua's
-- __index finds in the class's metatable (__getters) and calls.  Speed trick (measured): a
-- pinfo.number is a call into C that finds the getter (hashing "__getters") and calls it;
-- PG.number(pinfo) is the second call alone.  A getter is taken only when it exists and gives
-- what the documented attribute gives on the first packet's objects.
local PG = {}
wsapi.PG = PG
local function getter(obj, name)
    local mt = getmetatable(obj)
    local g = type(mt) == "table" and rawget(mt, "__getters")
    local f = type(g) == "table" and rawget(g, name)
    if type(f) ~= "function" then return documented(name) end
    local ok, a = pcall(f, obj)
    local b = obj[name]
    if not ok or (a ~= b and tostring(a) ~= tostring(b)) then return documented(name) end
    return f
end

-- (2) TreeItem's and Tvb's methods called through the class tables (speed trick, measured: -V
-- 16 us a frame less): ti:add(...) looks the method up through wslua's __index, a call into C,
-- each time.  Taken when the class table holds a function, and kept on the first packet only
-- if it is the very method an item finds.
local TI = {}
wsapi.TI = TI
local TI_METHODS = { "add", "set_hidden", "set_generated", "set_text", "append_text", "add_proto_expert_info" }
local function method(class, name)
    local ok, f = pcall(function() return class[name] end)
    if ok and type(f) == "function" then return f end
    return function(o, ...) return o[name](o, ...) end
end
for _, m in ipairs(TI_METHODS) do TI[m] = method(TreeItem, m) end
wsapi.tvb_raw = method(Tvb, "raw")

-- (3) "No tree at all" (tshark's summary pass): a TreeItem does not say so directly.  Its text
-- is nil both with no tree and with the sparse tree of -T fields / -Y on 4.6, but its
-- tostring() tells "has subtree=false" only when there is no tree (4.0 to 4.6).  Speed trick
-- (measured, 1.5 us a packet): before 4.6 a tree's root item is hidden (wslua's fake item)
-- and "no tree" is not, so one attribute read tells.  When unsure: a tree (slower, never wrong).
local major, minor = tostring(get_version and get_version() or ""):match("^(%d+)%.(%d+)")
major, minor = tonumber(major), tonumber(minor)
local hidden_tells = major ~= nil and (major < 4 or (major == 4 and minor < 6))
function wsapi.no_tree(tree)
    if hidden_tells then return not PG.hidden(tree) end
    return s_find(tostring(tree), "has subtree=false", 1, true) ~= nil
end
-- wsapi.has_tree(tree), not no_tree(tree), set by init: before 4.6 the getter of "hidden" itself
-- (speed trick, measured: no Lua call between the entry and it).
local function has_tree(tree) return not wsapi.no_tree(tree) end

-- (4) Whether somebody references a field in this dissection: TreeItem:referenced (documented
-- since 2.4: proto_field_is_referenced, true in a shown tree), asked of the dissection's root
-- item (tree.lua, REF).  In a tree nobody sees Wireshark adds a field only when it is referenced
-- (proto.c, TRY_TO_FAKE_THIS_ITEM: a field primed by a filter, coloring rule, custom column, tap
-- or extractor of that dissection); referenced answers true for every such field, so a field it
-- calls unreferenced would be faked anyway.  Called through the class table as (2), checked on
-- the first packet (init); a release without it: referenced (every field added: slower, never
-- wrong).
local function always() return true end
wsapi.referenced = method(TreeItem, "referenced")
local function check_referenced(tree)
    local ok, f = pcall(function() return tree.referenced end)
    if not ok or type(f) ~= "function" then return always end
    if f == wsapi.referenced then return f end
    return function(t, field) return t:referenced(field) end
end
-- Whether every dissection of a first pass (pinfo.visited false) is primed alike, so what the
-- first asked holds for the rest: outside the GUI (gui_enabled(), documented), where a first pass
-- is tshark's (its filters, taps, columns and extractors fixed at start; -2: the read filter's
-- pass), rawshark's or sharkd's load (its requests dissect visited frames).  The GUI's first pass
-- may change under a live capture (a new tap or coloring rule): there every dissection asks.
wsapi.first_pass_fixed = not (gui_enabled and gui_enabled())

function wsapi.init(pinfo, tree, tvb)
    for _, name in ipairs({ "number", "visited", "rel_ts", "src_port", "dst_port", "src", "dst", "cols",
        "p2p_dir" }) do
        PG[name] = getter(pinfo, name)
    end
    for _, name in ipairs({ "hidden", "visible" }) do PG[name] = getter(tree, name) end
    for _, m in ipairs(TI_METHODS) do
        if tree[m] ~= TI[m] then TI[m] = function(o, ...) return o[m](o, ...) end end
    end
    if tvb.raw ~= wsapi.tvb_raw then wsapi.tvb_raw = function(t, ...) return t:raw(...) end end
    wsapi.has_tree = hidden_tells and PG.hidden or has_tree
    wsapi.referenced = check_referenced(tree)
    wsapi.ready = true
end

-- (5) Environment switches, for the tests (docs/architecture.md): SHAREDLINK_NO_FAST=1 (the layout
-- cache off: every frame parsed field by field), SHAREDLINK_FAST_MARK=1 (mark the Info of the
-- packets the cache parsed), SHAREDLINK_PROBE_EACH_FRAME=1 (the referenced fields asked again in
-- every frame, not once a dissection).
local function env(name) return os.getenv("SHAREDLINK_" .. name) == "1" end
wsapi.env = { no_fast = env("NO_FAST"), fast_mark = env("FAST_MARK"), probe_each_frame = env("PROBE_EACH_FRAME") }

-- (6) Whether the packet is a UDP datagram (a datagram is one frame or several, each ending at
-- its ']': no CR LF needed; docs/fields-sharedlink.md, "Rules for real sessions"): pinfo.port_type
-- (documented) against epan's port_type enum, whose numbers the documented API does not name:
-- PT_TCP 2, PT_UDP 3 from 4.0 to 4.6.  Checked on each packet TCP may desegment
-- (pinfo.can_desegment > 0: a TCP segment), whose port type must be PT_TCP; when one is not, the
-- enum has moved and the documented fallback holds from then on: a packet with ports that TCP
-- cannot desegment is a datagram.  Read only for a frame without CR LF (a call into C each).
local PT_TCP, PT_UDP = 2, 3
local port_type_ok = true
function wsapi.is_udp(pinfo)
    if port_type_ok then
        local pt = pinfo.port_type
        if pt == PT_TCP or pinfo.can_desegment == 0 then return pt == PT_UDP end
        port_type_ok = false
    end
    return pinfo.can_desegment == 0 and (pinfo.src_port ~= 0 or pinfo.dst_port ~= 0)
end

return wsapi
