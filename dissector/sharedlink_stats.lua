-- SharedLink statistics for Wireshark: a Lua tap over the SharedLink dissector.
--
--   tshark -q -X lua_script:sharedlink.lua -X lua_script:sharedlink_stats.lua -r CAPTURE -z sharedlink,stats
--   tshark ... -z sharedlink,stats,FILTER     (only frames of packets matching the display filter)
--   Wireshark: Statistics > SharedLink
--
-- Needs dissector/sharedlink.lua loaded first (in a plugin folder files load in name order, so
-- sharedlink.lua comes before sharedlink_stats.lua). Wireshark 4.0 (Lua 5.2) and later (Lua 5.4).
--
-- Costs nothing until asked for: loading this file registers only the `-z` argument and the menu
-- item. The listener exists only once `-z sharedlink,stats` or the menu asks for it. No Field
-- extractor (Field.new) is created at all: Wireshark 4.0 answers every Field.new with a hidden
-- tap whose filter names the field, which makes every packet of every pass build a tree (a
-- summary pass 4x slower), asked for or not.
--
-- Reads fields, not a full tree: the listener's filter names every field counted below, which
-- makes Wireshark build just those items (and the sharedlink/sharedlink.var items they sit in)
-- in its fake tree; the listener does not ask for all fields. all_field_infos() then yields that
-- short list in tree order: a "sharedlink" item starts each frame, a "sharedlink.var" item each
-- variable (a packet can hold several SharedLink frames).
--
-- Counts the same way as `sharedlink stats` (pytools/sharedlink/analysis/stats.py), and the
-- way Expert Information counts:
--  * frames per kind (sharedlink.kind) and per node pair, written as the packet list writes it:
--    "B→A" (from B to A); a malformed frame (a "[:" that starts no well-formed frame) is a frame
--    of the pair its header names ("?" for a letter it lacks);
--  * noise: the "sharedlink" items with sharedlink.noise (bytes outside any frame), never frames;
--  * checksum failures: frames with sharedlink.checksum.status == 0 (Bad), one per
--    sharedlink.checksum.bad expert;
--  * sync late: frames with the sharedlink.sync.is_late field, which sharedlink.lua adds exactly
--    where it adds the sharedlink.sync.late expert (so one per expert), whatever the checksum;
--  * per node pair and variable: the number of values carried in frames with a good (or no)
--    checksum -- a value carried forward (sharedlink.var.carried) is not counted, nor the values
--    a malformed frame shows -- and the last such value.

-- luacheck: read globals report_failure all_field_infos register_stat_cmd_arg gui_enabled TextWindow
-- luacheck: read globals retap_packets register_menu MENU_STAT_UNSORTED set_plugin_info Dissector Listener

if set_plugin_info then
    set_plugin_info({
        version = "1.3.0",
        description = "SharedLink statistics (tshark -z sharedlink,stats; Statistics > SharedLink)",
        author = "SharedLink analyzer project",
        repository = "dissector/sharedlink_stats.lua",
    })
end

-- the fields the listener's filter primes, in no particular order; "sharedlink" and
-- "sharedlink.var" are the frame and variable items the walk groups by
local COUNTED = {
    "sharedlink", "sharedlink.kind", "sharedlink.src", "sharedlink.dst", "sharedlink.var",
    "sharedlink.var.name", "sharedlink.var.value", "sharedlink.var.carried",
    "sharedlink.checksum.status", "sharedlink.sync.is_late", "sharedlink.noise",
}
local ARROW = "\226\134\146" -- U+2192, as in the packet list's "B→A"
local TAP_FILTER = table.concat(COUNTED, " || ")

-- (Dissector.get answers nil for an unknown name on 4.0 and raises an error on some releases)
local have_dissector, sharedlink_dissector = pcall(Dissector.get, "sharedlink")
if not (have_dissector and sharedlink_dissector) then
    report_failure("sharedlink_stats.lua: the SharedLink dissector (sharedlink.lua) is not loaded, so there are "
        .. "no sharedlink.* fields to count. Load sharedlink.lua first (tshark -X lua_script:sharedlink.lua "
        .. "-X lua_script:sharedlink_stats.lua), or put both files in the same plugin folder.")
    return
end

-- The counting, the tables and the listener: sharedlink/stats_tap.lua beside this file, run the first
-- time a listener is asked for, so that a capture read without -z sharedlink,stats never holds
-- their code (compiled functions are live Lua heap, which the collector walks for every plugin:
-- docs/perf-log.md, 7 December 2026). Compiled once at load as well, so that a missing or broken
-- file says so when Wireshark starts.
local TAP_FILE = ((debug.getinfo(1, "S").source or ""):match("^@(.*[/\\])") or "") .. "sharedlink/stats_tap.lua"
assert(loadfile(TAP_FILE))
local M -- the module once run
local function stats()
    M = M or assert(loadfile(TAP_FILE))({ sharedlink_module = true }, { ARROW = ARROW })
    return M
end

-- ---------------------------------------------------------------------------------------------
-- the listener, made only on demand

-- "sharedlink,stats[,FILTER]" -> the filter shown, the listener's filter
local function tap_filter(arg)
    local filter = ""
    if type(arg) == "string" then
        filter = arg:gsub("^sharedlink,stats,?", "")
    end
    if filter ~= "" then return filter, "(" .. filter .. ") && (" .. TAP_FILTER .. ")" end
    return nil, TAP_FILTER
end

-- tshark -z sharedlink,stats[,FILTER]: print the tables at the end
register_stat_cmd_arg("sharedlink,stats", function(arg)
    local filter, dfilter = tap_filter(arg)
    stats().new_listener(dfilter, function(st) print(stats().render(st, filter)) end)
end)

-- Wireshark: Statistics > SharedLink, a text window refreshed on retap. MENU_STAT_UNSORTED: the
-- Qt GUI of 4.0 does not show the MENU_STAT_GENERIC group at all; the unsorted group is shown
-- in the Statistics menu by 4.0, 4.4 and 4.6.
if gui_enabled() then
    local function open_window()
        local tw = TextWindow.new("SharedLink statistics")
        local tap = stats().new_listener(TAP_FILTER, function(st) tw:set(stats().render(st)) end,
            function() tw:clear() end)
        tw:set_atclose(function() tap:remove() end)
        retap_packets()
    end
    register_menu("SharedLink", open_window, MENU_STAT_UNSORTED)
end
