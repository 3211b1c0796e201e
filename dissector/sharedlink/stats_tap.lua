-- SharedLink statistics' counting, tables and listener (sharedlink_stats.lua's), split from it so
-- that their code is compiled only when a listener is asked for (tshark -z sharedlink,stats, or
-- Statistics > SharedLink): until then it is not in the live Lua heap, whose size sets the
-- collector's work for every plugin (docs/perf-log.md, 7 December 2026).
--
-- Run by sharedlink_stats.lua alone (stats()); Wireshark also runs every .lua file of a plugin
-- folder's subfolders as a plugin of its own, and sharedlink.lua loads only the modules it names:
-- this file then does nothing.

-- luacheck: read globals all_field_infos Listener

local token, C = ...
if type(token) ~= "table" or token.sharedlink_module ~= true then return end

local ARROW = C.ARROW
local s_format, s_rep, t_concat, t_sort = string.format, string.rep, table.concat, table.sort
local M = {} -- what sharedlink_stats.lua calls: M.new_listener, M.render

-- ---------------------------------------------------------------------------------------------
-- counting

local function new_stats()
    return {
        frames = 0, bad = 0, late = 0, noise = 0,
        kinds = {},      -- kind -> frames
        pairs = {},      -- "B→A" -> { frames, bad, late, kinds = {} }
        vars = {},       -- "B→A\tname" -> { pair, name, count, last }
    }
end

local function inc(t, k) t[k] = (t[k] or 0) + 1 end

local function pair_stats(st, pair)
    local p = st.pairs[pair]
    if not p then
        p = { frames = 0, bad = 0, late = 0, kinds = {} }
        st.pairs[pair] = p
    end
    return p
end

local function add_values(st, pair, vars)
    for i = 1, #vars do
        local v = vars[i]
        if v.name and v.value ~= nil and not v.carried then
            local key = pair .. "\t" .. v.name
            local vs = st.vars[key]
            if not vs then
                vs = { pair = pair, name = v.name, count = 0 }
                st.vars[key] = vs
            end
            vs.count = vs.count + 1
            vs.last = v.value
        end
    end
end

-- Fold one frame (collected by the field walk) into the statistics. A "sharedlink" item with
-- sharedlink.noise is bytes outside any frame (the packet list's "noise"): counted apart, never a
-- frame. A malformed frame is a frame of the pair its header names; its values, shown as sent,
-- are no state (docs/fields-sharedlink.md, "Counts"), so not counted.
local function add_frame(st, fr)
    if not fr then return end
    if fr.noise then
        st.noise = st.noise + 1
        return
    end
    local kind = fr.kind or "?"
    local pair = (fr.src or "?") .. ARROW .. (fr.dst or "?")
    local p = pair_stats(st, pair)
    st.frames = st.frames + 1
    p.frames = p.frames + 1
    inc(st.kinds, kind)
    inc(p.kinds, kind)
    st.late = st.late + fr.late
    p.late = p.late + fr.late
    if fr.bad then
        st.bad = st.bad + 1
        p.bad = p.bad + 1
    elseif kind ~= "malformed" then
        add_values(st, pair, fr.vars)
    end
end

-- Walk the packet's primed fields; one table per SharedLink frame.
local function collect(st)
    local fr, var = nil, nil
    local infos = { all_field_infos() }
    for i = 1, #infos do
        local fi = infos[i]
        local name = fi.name
        if name == "sharedlink" then
            add_frame(st, fr)
            fr = { vars = {}, late = 0 }
            var = nil
        elseif fr then
            if name == "sharedlink.var" then
                var = {}
                fr.vars[#fr.vars + 1] = var
            elseif name == "sharedlink.var.name" then
                if var then var.name = tostring(fi.value) end
            elseif name == "sharedlink.var.value" then
                if var then var.value = tostring(fi.value) end
            elseif name == "sharedlink.var.carried" then
                if var then var.carried = fi.value and true or false end
            elseif name == "sharedlink.kind" then
                fr.kind = tostring(fi.value)
            elseif name == "sharedlink.src" then
                fr.src = tostring(fi.value)
            elseif name == "sharedlink.dst" then
                fr.dst = tostring(fi.value)
            elseif name == "sharedlink.checksum.status" then
                fr.bad = (fi.value == 0)
            elseif name == "sharedlink.sync.is_late" then
                fr.late = fr.late + 1
            elseif name == "sharedlink.noise" then
                fr.noise = true
            end
        end
    end
    add_frame(st, fr)
end

-- ---------------------------------------------------------------------------------------------
-- the report: aligned plain-text tables (columns separated by at least two spaces; the last
-- column of the variable table is the value, which may contain spaces)

local function sorted_keys(t)
    local keys = {}
    for k in pairs(t) do keys[#keys + 1] = k end
    t_sort(keys)
    return keys
end

-- width on screen of a UTF-8 string: its bytes less the continuation bytes
local function width(s)
    local _, cont = s:gsub("[\128-\191]", "")
    return #s - cont
end

-- rows of cells -> lines; align[c] is "l" or "r"; the last column is not padded
local function table_lines(out, rows, align)
    local w = {}
    for _, row in ipairs(rows) do
        for c, cell in ipairs(row) do w[c] = math.max(w[c] or 0, width(cell)) end
    end
    for _, row in ipairs(rows) do
        local cells = {}
        for c, cell in ipairs(row) do
            local pad = s_rep(" ", w[c] - width(cell))
            if c == #row and align[c] ~= "r" then pad = "" end
            cells[c] = (align[c] == "r") and (pad .. cell) or (cell .. pad)
        end
        out[#out + 1] = "  " .. t_concat(cells, "  ")
    end
end

-- a value as the packet details show it, on one line: CR, LF, TAB and a backslash escaped as
-- \r, \n, \t, \\, any other control byte as \xhh (so a value holding "\r\n" keeps its row)
local ESCAPE = { ["\r"] = "\\r", ["\n"] = "\\n", ["\t"] = "\\t", ["\\"] = "\\\\" }
local function one_line(v)
    return (v:gsub("[%c\\]", function(c) return ESCAPE[c] or s_format("\\x%02x", c:byte()) end))
end

local function render(st, filter)
    local out = {}
    local function line(...) out[#out + 1] = s_format(...) end
    local kinds = sorted_keys(st.kinds)
    line("===================================================================")
    line("SharedLink statistics%s", (filter and filter ~= "") and (" (filter: " .. filter .. ")") or "")
    line("Frames: %d", st.frames)
    line("Checksum failures: %d", st.bad)
    line("Sync late: %d", st.late)
    line("Noise: %d", st.noise)
    line("")
    line("Frames per kind")
    local rows = { { "Kind", "Frames" } }
    for _, k in ipairs(kinds) do rows[#rows + 1] = { k, tostring(st.kinds[k]) } end
    table_lines(out, rows, { "l", "r" })
    line("")
    line("Frames per node pair")
    rows = { { "Pair", "Frames", "Bad checksum", "Sync late" } }
    local align = { "l", "r", "r", "r" }
    for _, k in ipairs(kinds) do
        rows[1][#rows[1] + 1] = k
        align[#align + 1] = "r"
    end
    for _, key in ipairs(sorted_keys(st.pairs)) do
        local p = st.pairs[key]
        local row = { key, tostring(p.frames), tostring(p.bad), tostring(p.late) }
        for _, k in ipairs(kinds) do row[#row + 1] = tostring(p.kinds[k] or 0) end
        rows[#rows + 1] = row
    end
    table_lines(out, rows, align)
    line("")
    line("Variables")
    rows = { { "Pair", "Variable", "Count", "Last value" } }
    for _, k in ipairs(sorted_keys(st.vars)) do
        local v = st.vars[k]
        rows[#rows + 1] = { v.pair, v.name, tostring(v.count), one_line(v.last or "") }
    end
    table_lines(out, rows, { "l", "l", "r", "l" })
    -- link health (the dissector's health module: every frame of the first pass, whatever the filter)
    local health = package.loaded["sharedlink.health"]
    if health then health.report(out, table_lines) end
    line("===================================================================")
    return t_concat(out, "\n")
end

-- A listener feeding a fresh statistics table; draw(st) shows it. Not asking for all fields
-- (third argument false) is what keeps the tree to the primed fields.
local function new_listener(dfilter, draw, reset)
    local st = new_stats()
    local tap = Listener.new("frame", dfilter, false)
    function tap.packet() collect(st) end
    function tap.draw() draw(st) end
    function tap.reset()
        st = new_stats()
        if reset then reset() end
    end
    return tap
end

M.new_listener, M.render = new_listener, render
return M
