-- SharedLink statistics for Wireshark: a Lua tap over the SharedLink dissector.
--
--   tshark -q -X lua_script:sharedlink.lua -X lua_script:sharedlink_stats.lua -r CAPTURE -z sharedlink,stats
--   tshark ... -z sharedlink,stats,FILTER     (only frames of packets matching the display filter)
--   Wireshark: Statistics > SharedLink
--
-- Needs dissector/sharedlink.lua loaded first (in a plugin folder files load in name order, so
-- sharedlink.lua comes before sharedlink_stats.lua).
--
-- Counts the same way as `sharedlink stats` (pytools/sharedlink/stats.py):
--  * frames per kind (sharedlink.kind) and per node pair "B>A" (from B to A);
--  * checksum failures: sharedlink.checksum.status == 0 (Bad);
--  * per node pair and variable: the number of values carried in frames with a good (or no)
--    checksum -- a value carried forward (sharedlink.var.carried) is not counted -- and the last
--    such value;
--  * sync late: frames with the sharedlink.sync.late expert.
-- A packet can hold several SharedLink frames: the tap walks the packet's fields in tree order
-- (all_field_infos), a "sharedlink" protocol item starting each frame and a "sharedlink.var"
-- item each variable.

-- luacheck: read globals report_failure all_field_infos register_stat_cmd_arg gui_enabled TextWindow
-- luacheck: read globals retap_packets register_menu MENU_STAT_GENERIC MENU_STAT_UNSORTED

local ok, fields = pcall(function()
    return {
        kind = Field.new("sharedlink.kind"),
        src = Field.new("sharedlink.src"),
        dst = Field.new("sharedlink.dst"),
        var_name = Field.new("sharedlink.var.name"),
        var_value = Field.new("sharedlink.var.value"),
        var_carried = Field.new("sharedlink.var.carried"),
        checksum_status = Field.new("sharedlink.checksum.status"),
    }
end)
if not ok then
    report_failure("sharedlink_stats.lua: the SharedLink dissector (sharedlink.lua) is not loaded, so there are "
        .. "no sharedlink.* fields to count. Load sharedlink.lua first (tshark -X lua_script:sharedlink.lua "
        .. "-X lua_script:sharedlink_stats.lua), or put both files in the same plugin folder.")
    return
end

local f_kind = fields.kind
local s_format, t_concat, t_sort = string.format, table.concat, table.sort

local function new_stats()
    return {
        frames = 0, bad = 0, late = 0,
        kinds = {},      -- kind -> frames
        pairs = {},      -- "B>A" -> { frames, bad, late, kinds = {} }
        vars = {},       -- "B>A\tname" -> { pair, name, count, last }
    }
end

local function inc(t, k) t[k] = (t[k] or 0) + 1 end

-- Fold one frame (collected from the field walk) into the statistics.
local function add_frame(st, fr)
    if not fr then return end
    local kind = fr.kind or "unknown"
    local pair = (fr.src or "?") .. ">" .. (fr.dst or "?")
    st.frames = st.frames + 1
    inc(st.kinds, kind)
    local p = st.pairs[pair]
    if not p then
        p = { frames = 0, bad = 0, late = 0, kinds = {} }
        st.pairs[pair] = p
    end
    p.frames = p.frames + 1
    inc(p.kinds, kind)
    if fr.bad then
        st.bad = st.bad + 1
        p.bad = p.bad + 1
        return
    end
    if fr.late then
        st.late = st.late + 1
        p.late = p.late + 1
    end
    for i = 1, #fr.vars do
        local v = fr.vars[i]
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

-- Walk the packet's fields; one table per SharedLink frame.
local function collect(st)
    if not f_kind() then return end
    local fr, var = nil, nil
    local infos = { all_field_infos() }
    for i = 1, #infos do
        local fi = infos[i]
        local name = fi.name
        if name == "sharedlink" then
            add_frame(st, fr)
            fr = { vars = {} }
            var = nil
        elseif fr and name:sub(1, 11) == "sharedlink." then
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
            elseif name == "sharedlink.sync.late" then
                fr.late = true
            end
        end
    end
    add_frame(st, fr)
end

local function sorted_keys(t)
    local keys = {}
    for k in pairs(t) do keys[#keys + 1] = k end
    t_sort(keys)
    return keys
end

local function kinds_text(kinds)
    local parts = {}
    for _, k in ipairs(sorted_keys(kinds)) do parts[#parts + 1] = k .. "=" .. kinds[k] end
    return t_concat(parts, " ")
end

-- The report: plain text, one table per section (machine-readable: columns separated by two or
-- more spaces; the last column of the variable table is the value, which may contain spaces).
local function render(st, filter)
    local out = {}
    local function line(...) out[#out + 1] = s_format(...) end
    line("===================================================================")
    line("SharedLink statistics%s", (filter and filter ~= "") and (" (filter: " .. filter .. ")") or "")
    line("Frames: %d", st.frames)
    line("Checksum failures: %d", st.bad)
    line("Sync late: %d", st.late)
    line("")
    line("Frames per kind")
    line("  %-14s  %8s", "Kind", "Frames")
    for _, k in ipairs(sorted_keys(st.kinds)) do line("  %-14s  %8d", k, st.kinds[k]) end
    line("")
    line("Frames per node pair")
    line("  %-6s  %8s  %12s  %9s  %s", "Pair", "Frames", "Bad checksum", "Sync late", "Kinds")
    for _, k in ipairs(sorted_keys(st.pairs)) do
        local p = st.pairs[k]
        line("  %-6s  %8d  %12d  %9d  %s", k, p.frames, p.bad, p.late, kinds_text(p.kinds))
    end
    line("")
    line("Variables")
    line("  %-6s  %-20s  %8s  %s", "Pair", "Variable", "Count", "Last value")
    for _, k in ipairs(sorted_keys(st.vars)) do
        local v = st.vars[k]
        line("  %-6s  %-20s  %8d  %s", v.pair, v.name, v.count, v.last or "")
    end
    line("===================================================================")
    return t_concat(out, "\n")
end

local function display_filter(arg)
    local filter = ""
    if type(arg) == "string" then
        filter = arg:gsub("^sharedlink,stats,?", "")
    end
    if filter ~= "" then return filter, "sharedlink && (" .. filter .. ")" end
    return nil, "sharedlink"
end

-- tshark -z sharedlink,stats[,FILTER]: print the table at the end
register_stat_cmd_arg("sharedlink,stats", function(arg)
    local st = new_stats()
    local filter, dfilter = display_filter(arg)
    local tap = Listener.new("frame", dfilter, true)
    function tap.packet() collect(st) end
    function tap.draw() print(render(st, filter)) end
    function tap.reset() st = new_stats() end
end)

-- Wireshark: Statistics > SharedLink, in a text window refreshed on retap
if gui_enabled() then
    local function menu()
        local tw = TextWindow.new("SharedLink statistics")
        local st = new_stats()
        local tap = Listener.new("frame", "sharedlink", true)
        tw:set_atclose(function() tap:remove() end)
        function tap.packet() collect(st) end
        function tap.draw() tw:set(render(st)) end
        function tap.reset()
            st = new_stats()
            tw:clear()
        end
        retap_packets()
    end
    register_menu("SharedLink", menu, MENU_STAT_GENERIC or MENU_STAT_UNSORTED)
end
