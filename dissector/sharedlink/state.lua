-- SharedLink dissector module: state, what a direction remembers (values, names, lists, the sync clock, pending
-- queries) and the one place that writes it on the first pass or reads it back on later ones.
-- Loaded by sharedlink.lua (load_module); Wireshark also runs every .lua file of a plugin folder's
-- subfolders as a plugin of its own: this file then does nothing.

local token, M = ...
if type(token) ~= "table" or token.sharedlink_module ~= true then return end

local U, cfg, wsapi, tostring = M.util, M.prefs, M.wsapi, tostring
local F = M.parse.F   -- the frame record (parse.lua)
local floor, valid_type, VT, VN = math.floor, U.valid_type, F.VT, F.VN
local VV, VI, VR, slot_name = F.VV, F.VI, F.VR, U.slot_name
local LETTER = U.LETTER

local LIM = cfg.LIM   -- the limits and their per-capture facts (prefs; the same table for ever)
local R = M.records
local PG = wsapi.PG
local get_rec, carried_store, subset_line, CARRY, MISS = R.get_rec, R.carried_store, R.subset_line, R.CARRY, R.MISS

-- Per-capture state (reset by S.reset)
local dirs          -- direction key -> direction state
local pair_lists    -- "SD" letters -> learnt list (the pair's latest good declaration)
local inbound       -- receiver key (addresses, "|", letters: see list_in_use) -> its inbound (L) list
local ninbound      -- receivers with an inbound list (at most max_conversations)
local pending_q     -- ask key .. ":" .. name (or "#N", "#L": a list request) -> record of the asking frame
local decl_lists    -- a declared list's content (names and types) -> the first list declared with it
local dir_cache_num, dir_cache_ports -- the packet whose attributes were read last, its ports
local last_asrc, last_adst, last_pdir, last_byaddr  -- addresses of the last packet and their dirs entry
local stamp_ctr = 0
-- lists_gen: bumped whenever a list a direction with none of its own may use changes (a
-- declaration, a new capture, the preferences); a direction keeps the one it found (d.lcur) while
-- d.lgen is the same (speed trick, measured: no three table lookups a frame, list_in_use)
local lists_gen = 0
local NO_VALUES = { n = 0, N = {} }   -- (state_data; its subs emptied by S.reset)
local S = {}
function S.lists_changed() lists_gen = lists_gen + 1 end
function S.reset()
    lists_gen = lists_gen + 1
    dirs, pair_lists, pending_q, inbound, ninbound = {}, {}, {}, {}, 0
    decl_lists, NO_VALUES.subs = {}, nil
    dir_cache_num, dir_cache_ports = nil, 0
    last_asrc, last_adst, last_pdir, last_byaddr = nil, nil, nil, nil
end
S.reset()

------------------------------------------------------------------------------
-- Direction state
------------------------------------------------------------------------------
-- vals/from: name -> last good value / its frame; names: named variables in the order first
-- sent in a good frame, npos: name -> its index there, nfirst: name -> that frame;
-- seen: name -> stamp of the last frame that had it; filled: slot -> true once it held a value
-- (a required slot), maxslot: the highest; first/lastfull: times of the first frame and of the
-- last good full one.
-- sgen: bumped when the direction learns a name (its known subsets, kept by each layout in
-- named.subs[d] with the sgen they were made at, are then made again: known_subset).
-- pos: the direction's last good data frame had D fields alone (positional), so a bare N0 is a
-- positional frame of no slot (nil: named, or none yet; store_values).
local NO_SUBSETS = {}   -- (named.subs of a layout with none: never written)
local function new_dir()
    return { vals = {}, from = {}, names = {}, npos = {}, nfirst = {}, nkey = {}, seen = {}, filled = {}, maxslot = -1,
        first = nil, lastfull = nil, list = nil, sgen = 0, wl = false }
end

-- A new direction at byaddr[key]; past max_conversations one that is kept nowhere (d.over: made
-- anew each frame, so it never knows a name; state_data counts on it).
local function add_dir(byaddr, key)
    local d = new_dir()
    d.akey = byaddr.akey   -- its addresses (and serial direction): the receiver's key, with its letters
    if LIM.ndirs >= LIM.max_conversations then d.over = true; return d end
    LIM.ndirs = LIM.ndirs + 1
    byaddr[key] = d
    return d
end

-- wsapi's getters (PG) of the attributes read each packet, as upvalues (a table's field is a hash
-- lookup: speed trick, measured), taken by the entry on the first packet, once wsapi.init has
-- chosen them (S.take_getters).
local g_sport, g_dport, g_src, g_dst, g_p2p_dir, g_rel_ts
function S.take_getters()
    g_sport, g_dport, g_src, g_dst, g_p2p_dir, g_rel_ts = PG.src_port, PG.dst_port, PG.src, PG.dst, PG.p2p_dir,
        PG.rel_ts
end

-- The dirs entry of the current packet's addresses (and capture direction: pdir), made the
-- packet's (last_byaddr).
local function packet_addrs(asrc, adst, pdir)
    local akey = tostring(asrc) .. ">" .. tostring(adst) .. "/" .. pdir
    local byaddr = dirs[akey]
    if not byaddr then
        byaddr = { akey = akey }
        dirs[akey] = byaddr
    end
    last_asrc, last_adst, last_pdir, last_byaddr = asrc, adst, pdir, byaddr
end

-- Direction state for (src address, dst address, src port, dst port, letters).
-- dirs[addresses][ports and letters as one number]; cheap on the per-frame path: the attributes
-- are read once a packet (dir_cache_num), and the key text of the addresses is rebuilt (and
-- looked up) only when they differ from the previous packet's (speed trick, measured: Address
-- objects compare cheaper than they print).  The capture direction only where no port tells the
-- directions apart (a serial line): a UDP/TCP flow is one direction whatever direction flags its
-- link layer had.
local function get_dir(pinfo, num, dstb, srcb)
    if dir_cache_num ~= num then
        local sport, dport = g_sport(pinfo), g_dport(pinfo)
        local asrc, adst = g_src(pinfo), g_dst(pinfo)
        local pdir = (sport == 0 and dport == 0) and g_p2p_dir(pinfo) or -1
        if pdir ~= last_pdir or asrc ~= last_asrc or adst ~= last_adst then packet_addrs(asrc, adst, pdir) end
        dir_cache_num, dir_cache_ports = num, (sport * 65536 + dport) * 65536
    end
    local byaddr, key = last_byaddr, dir_cache_ports + dstb * 256 + srcb
    return byaddr[key] or add_dir(byaddr, key)
end

-- The address key (as get_dir's) of the reverse direction (dst -> src) of the current packet.
local function rev_akey(pinfo)
    local pd = -1
    if pinfo.src_port == 0 and pinfo.dst_port == 0 then
        pd = pinfo.p2p_dir
        if pd == 0 or pd == 1 then pd = 1 - pd end
    end
    return tostring(pinfo.dst) .. ">" .. tostring(pinfo.src) .. "/" .. pd
end

-- The keys of a query sent on the current packet (its querier's address and port, the queried
-- address, the letters) and of the query a reply sent on it answers (it comes from the queried
-- address and goes to the querier's address and port, whatever its source port); a serial line
-- by its capture direction.  docs/fields-sharedlink.md, "Replies".
local function ask_keys(pinfo, src, dst)
    local sport, dport = pinfo.src_port, pinfo.dst_port
    local a, b = tostring(pinfo.src), tostring(pinfo.dst)
    if sport == 0 and dport == 0 then
        local pd = pinfo.p2p_dir
        local rpd = (pd == 0 or pd == 1) and 1 - pd or pd
        return a .. ">" .. b .. "/" .. pd .. "|" .. src .. dst, b .. ">" .. a .. "/" .. rpd .. "|" .. dst .. src
    end
    return a .. ":" .. sport .. ">" .. b .. "|" .. src .. dst, b .. ":" .. dport .. ">" .. a .. "|" .. dst .. src
end

-- The list a direction with no list of its own uses (docs/fields-sharedlink.md, "Lists by
-- receiver"): its receiver's inbound list, its letter pair's latest declaration, the user's list
-- for the pair, the a-priori list (cfg.list, by_length).
local function source_list(rkey, letters)
    return inbound[rkey] or pair_lists[letters] or cfg.pairs[letters] or cfg.list
end

-- The list a positional frame is named by: the a-priori list names only a frame with as many
-- slots as it has (ordinal + D fields); another frame gets none (#i, no warning).
local NOLIST = { t = {} }
local function frame_list(list)
    if list.by_length and F.n_pos > 0 and (F.n_ord or 0) + F.n_pos ~= #list then return NOLIST end
    return list
end

-- A name's type in a list (nil: untyped or not in it); a reply's values are typed by it.
local function list_type(list, name)
    local tn = list.tn
    if not tn then
        tn = {}
        local t = list.t
        for k = #list, 1, -1 do if t[k] then tn[list[k]] = t[k] end end
        list.tn = tn
    end
    return tn[name]
end

-- A direction takes a new list (docs/fields-sharedlink.md, "A declaration replaces its direction's
-- list"): the names it keeps keep their values and "once filled" marks (at their new slots), the
-- others (not sent in named frames) lose them; slots past its end are no longer required.  The
-- marked names are those of the filled slots as the last stored positional frame named them
-- (d.eff: the list it was named by, else the old list), as the Python twin does
-- (VariableTable.use_list).
local function replace_values(d, old, list)
    local keep, vals, from, npos = {}, d.vals, d.from, d.npos
    local eff, marked = d.eff or old, {}
    for slot in pairs(d.filled) do marked[slot_name(eff, slot)] = true end
    for k = 1, #list do keep[list[k]] = true end
    for name in pairs(vals) do
        if not keep[name] and npos[name] == nil then vals[name] = nil; from[name] = nil end
    end
    local maxslot, filled = -1, {}
    for k = 1, #list do
        if marked[list[k]] then maxslot = k - 1; filled[k - 1] = true end
    end
    d.maxslot, d.filled, d.eff = maxslot, filled, nil
    d.wl = false   -- (state_data makes a subset's line again)
end

-- The journal: linear state for a direction with many names.  A direction with up to
-- JOURNAL_NAMES names stores, for each frame that leaves some out, their values in the frame's
-- record (cheap, few objects: see carried_store).  Past that, a copy per frame would grow with
-- the names (quadratic), so the direction keeps instead, for each name, the values it took and
-- the frames they came from (d.hist[name] = { key, value, key, value, ... }, a frame's key
-- num * 2^20 + its offset in the packet: frames in capture order) and d.nkey, the key of the
-- frame each name was first sent in (in the order of d.names); a later pass finds what a frame
-- carried from them.  d.jkey: the key of the first frame judged by the journal.
local JOURNAL_NAMES = 32
local journal
do
    local function fkey(num, sk) return num * 1048576 + sk % 1048576 end

    local function start(d, key)
        local hist, vals, from = {}, d.vals, d.from
        for _, name in ipairs(d.names) do
            hist[name] = { (from[name] or 0) * 1048576, vals[name] or false }
        end
        d.hist, d.jkey = hist, key
        LIM.journal = true
        return hist
    end

    local function set(hist, name, key, val)
        local h = hist[name]
        if not h then h = {}; hist[name] = h end
        local n = #h
        if n > 0 and h[n - 1] == key then h[n] = val else h[n + 1], h[n + 2] = key, val end
    end

    -- the value name had before the frame of key (and its frame), false, false when none
    local function get(h, key)
        if not h then return false, false end
        local lo, hi, found = 1, #h / 2, nil
        while lo <= hi do
            local mid = floor((lo + hi) / 2)
            if h[2 * mid - 1] < key then found = mid; lo = mid + 1 else hi = mid - 1 end
        end
        if not found then return false, false end
        return h[2 * found], floor(h[2 * found - 1] / 1048576)
    end

    -- how many names the direction knew at the frame of key (first sent at or before it)
    local function known_at(d, key)
        local nk = d.nkey
        local lo, hi, found = 1, #nk, 0
        while lo <= hi do
            local mid = floor((lo + hi) / 2)
            if nk[mid] <= key then found = mid; lo = mid + 1 else hi = mid - 1 end
        end
        return found
    end

    -- A later pass, a named data frame the journal judged: the number of names it carried, and
    -- with fill, the names in MISS (name, value, frame, ...; nm entries) as the first pass had them.
    local PRESENT, pstamp = {}, 0
    local function missing(d, key, fill)
        pstamp = pstamp + 1
        local npos, nk, present = d.npos, d.nkey, 0
        for v = 1, F.nv do
            local name = VN[v]
            if name and VV[v] and PRESENT[name] ~= pstamp then
                local i = npos[name]
                if i and nk[i + 1] <= key then present = present + 1 end
                PRESENT[name] = pstamp
            end
        end
        local known = known_at(d, key)
        local nm = 0
        if fill then
            local names, hist = d.names, d.hist
            for k = 1, known do
                local name = names[k]
                if PRESENT[name] ~= pstamp then
                    local cv, cf = get(hist[name], key)
                    MISS[nm + 1], MISS[nm + 2], MISS[nm + 3] = name, cv, cf
                    nm = nm + 3
                end
            end
        end
        return known - present, nm
    end
    journal = { key = fkey, start = start, set = set, missing = missing }
end

-- state_data, state_other and their helpers (a block).  lim_hit: the limit the frame being
-- stored hit ("Limit exceeded: ..." text; false: none), for its record.
local state_data, state_other
do
    local lim_hit = false
    -- The state writer's facts about the current data frame (upvalues, set by data_values):
    -- dv_stamp marks the names it has (d.seen), dv_present counts them (distinct known names),
    -- dv_ne the carried values of its empty D fields in CARRY, dv_maxslot its highest positional
    -- slot, dv_required: a slot that held a value is empty here (or the frame's N is past range).
    local dv_stamp, dv_present, dv_ne, dv_maxslot, dv_required = 0, 0, 0, -1, false

    -- A named value: a new name is learnt (good checksum, within max_names), a known one stored.
    local function named_value(d, name, val, good, num, sk, hist, key)
        local st = d.seen[name]
        if not st and good then
            local names = d.names
            if #names < LIM.max_names then
                names[#names + 1] = name
                d.npos[name] = #names - 1
                d.nfirst[name] = num
                d.nkey[#names] = key or journal.key(num, sk)
                d.names_is, d.sgen = nil, d.sgen + 1   -- (known_subset's made again)
                st = 0
            else
                -- a new name past max_names: no state
                lim_hit = "Limit exceeded: more than " .. LIM.max_names ..
                    " names in this direction (max_names)"
            end
        end
        if not st then return end
        if good then
            d.vals[name], d.from[name] = val, num
            if hist then journal.set(hist, name, key, val) end
        end
        if st ~= dv_stamp then dv_present = dv_present + 1; d.seen[name] = dv_stamp end
    end

    -- A positional value at slot (named by list): stored, or carried when empty.
    local function positional_value(d, list, slot, val, good, num)
        local name = slot_name(list, slot)
        if slot > dv_maxslot then dv_maxslot = slot end
        if val == "" then
            if d.filled[slot] then dv_required = true end
            CARRY[dv_ne + 1], CARRY[dv_ne + 2] = d.vals[name] or false, d.from[name] or false
            dv_ne = dv_ne + 2
        elseif good then
            d.vals[name], d.from[name] = val, num
            d.filled[slot] = true
            if slot > d.maxslot then d.maxslot = slot end
        end
    end

    -- The direction's known names this frame left out, into MISS (name, value, frame, ...); returns
    -- nm (MISS's entries) and how many.
    local function missing_names(d)
        local names, seen, vals, from = d.names, d.seen, d.vals, d.from
        local nm, miss_n = 0, 0
        for k = 1, #names do
            local name = names[k]
            if seen[name] ~= dv_stamp then
                MISS[nm + 1], MISS[nm + 2], MISS[nm + 3] = name, vals[name] or false, from[name] or false
                nm = nm + 3
                miss_n = miss_n + 1
            end
        end
        return nm, miss_n
    end

    -- A good frame with D fields, after its values are stored: the names its slots were stored by
    -- (d.eff), and the direction's form (d.pos): D fields alone are positional, a named value named.
    local function positional_form(d, list)
        if dv_maxslot >= 0 then d.eff = list end
        if F.nq == 0 then
            if not d.pos then d.pos, d.names_is, d.sgen = true, nil, d.sgen + 1 end
        elseif d.pos then
            d.pos = nil
        end
    end

    -- Every value of the frame into the state; returns nm and the number of named variables carried.
    local function store_values(d, list, num, sk, good, has_tree, hist, key)
        stamp_ctr = stamp_ctr + 1
        -- an N past to_ordinal's range (F.huge_ord) stores nothing and is never a full set; nor is
        -- one that is no number (F.n_nan: N?, Nx, N+0; its values stored from slot 0)
        dv_stamp, dv_present, dv_ne, dv_maxslot, dv_required = stamp_ctr, 0, 0, -1, F.huge_ord or F.n_nan or false
        local max_slots = LIM.max_slots
        for v = 1, F.nv do
            local val = VV[v]
            if val then
                local name = VN[v]
                if name then
                    named_value(d, name, val, good, num, sk, hist, key)
                elseif VI[v] < max_slots then
                    positional_value(d, list, VI[v], val, good, num)
                end
            end
        end
        if F.n_pos > 0 then
            if good then positional_form(d, list) end
            -- positional: a required slot past the frame's last D (d.maxslot is one)
            if dv_maxslot < d.maxslot then dv_required = true end
            return 0, 0
        end
        if d.pos then
            -- a bare N in a positional direction: a positional frame of no slot, nothing carried
            -- (docs/fields-sharedlink.md, "Values": a bare N0 takes its direction's form)
            if F.nv == 0 then return 0, 0 end
            if good then d.pos = nil end
        end
        if #d.names == 0 then return 0, 0 end
        -- named: known variables missing from this frame (a journal: counted; listed only for a
        -- tree, kept in no record)
        if hist then return (has_tree and missing_names(d) or 0), #d.names - dv_present end
        return missing_names(d)
    end

    -- The direction's known names a named layout leaves out, in the direction's order (nil: the
    -- layout names one the direction does not know, or leaves none out), kept by the layout in
    -- named.subs[d] (read by state_data) until the direction learns another name (named_value bumps
    -- d.sgen; speed trick, measured: a compressed stream's deltas).  Kept by the layout, not the
    -- direction: a layout the layout cache drops (parse.lua, MAX_LAYOUTS a node pair) takes its
    -- subsets with it (issue 44: a direction's own table kept every layout it ever met alive).
    local function known_subset(d, named)
        if d.pos then return nil end   -- (a positional direction: data_general tells the form)
        local names = d.names
        if #names > JOURNAL_NAMES and not d.over then return nil end   -- a journal's (data_values)
        local npos, sn, in_layout = d.npos, named.N, {}
        for k = 1, named.n do
            if not npos[sn[k]] then return nil end
            in_layout[sn[k]] = true
        end
        local miss = {}
        for k = 1, #names do
            if not in_layout[names[k]] then miss[#miss + 1] = names[k] end
        end
        if #miss == 0 then return nil end
        local sub = { names = miss, n = #miss, line = false, run = false, lsk = false, gen = d.sgen }
        if d.over then return sub end   -- (made anew each frame: nothing kept for it)
        local cache = named.subs
        if not cache then cache = {}; named.subs = cache end
        cache[d] = sub
        return sub
    end

    -- The carried names (a known subset's) into MISS: name, value, frame, ...; returns nm.
    local function carried_subset(d, names)
        local vals, from, nm = d.vals, d.from, 0
        for k = 1, #names do
            local name = names[k]
            MISS[nm + 1], MISS[nm + 2], MISS[nm + 3] = name, vals[name] or false, from[name] or false
            nm = nm + 3
        end
        return nm
    end


    -- After store_values (miss_n named variables carried): whether the direction's names are now
    -- the whole set of the frame's named layout (d.names_is), and the frame's verdicts, full and
    -- full_local (see data_values).
    local function stored_verdict(d, named, good, miss_n, full_local)
        -- (never a journal's: state_data takes the whole set without looking for one)
        if named and good and miss_n == 0 and #d.names == named.n and not d.hist then d.names_is = named end
        local n_ord = F.n_ord
        local full = F.nd > 0 and (n_ord == nil or n_ord == 0) and not dv_required and miss_n == 0
        if F.n_pos == 0 then full_local = full_local and miss_n == 0 end
        return full, full_local
    end

    -- State, first pass, a data frame: its values go into the direction's state (good checksum),
    -- what it leaves out is gathered in CARRY (empty D fields: value, frame, ...; ne entries) and
    -- MISS (named variables: name, value, frame, ...; nm entries).  Returns whether it is full,
    -- ne, nm, the number of named variables carried, full_local (the verdict without state), nm for
    -- the record (0 for a journal's).
    local function data_values(d, list, num, sk, good, full_local, has_tree)
        local named = F.named
        local hist, key = d.hist, nil
        if hist or #d.names > JOURNAL_NAMES then
            key = journal.key(num, sk)
            if not hist and not d.over then hist = journal.start(d, key) end
        end
        local nm, miss_n = store_values(d, list, num, sk, good, has_tree, hist, key)
        local full
        full, full_local = stored_verdict(d, named, good, miss_n, full_local)
        -- a journal's carried names go in no record (see journal)
        return full, dv_ne, nm, miss_n, full_local, hist and 0 or nm
    end

    -- The carried values of empty D fields (CARRY, ne) and named ones (MISS, nm) into a table record.
    local function carried_record(rec, ne, nm)
        for k = 1, ne do rec[k] = CARRY[k] end
        if nm > 0 then
            local miss = {}
            for k = 1, nm do miss[k] = MISS[k] end
            rec.miss = miss
        end
    end

    -- The record of a data frame that carries values (or whose kind the fields alone do not tell:
    -- a record with its kind; see data_record): a packed text line unless the frame has a table
    -- record anyway.  Returns the record (nil: a line).
    local function data_carried(rec, num, sk, ne, nm, kch)
        if ne > 0 or nm > 0 then
            if rec or not carried_store(num, sk, ne, nm, kch) then
                rec = rec or get_rec(num, sk, true)
                carried_record(rec, ne, nm)
            end
        else
            rec = rec or get_rec(num, sk, true)
        end
        return rec
    end

    -- The sync clock at the current packet (rel_ts) for direction d: a full frame (good checksum)
    -- sets it; a delta past the interval is late.  Returns the record (rec, or a table record
    -- with its late sync: rec.late) and the packet's time.
    local function sync_clock(pinfo, d, num, sk, full, cs_status, rec)
        local now = g_rel_ts(pinfo)
        local first = d.first
        if not first then first = now; d.first = now end
        if full then
            if cs_status ~= 0 then d.lastfull = now end   -- a good checksum (or none)
        else
            local age = now - (d.lastfull or first)
            if age > cfg.sync then
                rec = rec or get_rec(num, sk, true)
                rec.late = age
            end
        end
        return rec, now
    end

    -- State, first pass, a data frame: the sync clock, and the record later passes read (late
    -- sync, carried values, a kind the fields alone do not tell).  Returns state_data's answers (the
    -- kind, the record, and list, d, the carried counts: the upvalues dr_miss (named variables
    -- carried), dr_ne (CARRY's entries), dr_tree_nm (MISS's entries for a tree), and the packet's
    -- time; a tail call).
    -- dr_nm: MISS's entries for the record (0: none, or a journal's, which go in no record).  A
    -- frame past a limit (lim_hit) gets a table record with it.
    local dr_ne, dr_nm, dr_miss, dr_tree_nm = 0, 0, 0, 0
    local function data_record(pinfo, d, num, sk, full, full_local, cs_status, list)
        local ne, nm = dr_ne, dr_nm
        local rec = lim_hit and get_rec(num, sk, true) or nil   -- a limit's expert: a table record
        local now
        rec, now = sync_clock(pinfo, d, num, sk, full, cs_status, rec)
        local kch = full and "f" or "d"
        if ne > 0 or nm > 0 or full ~= full_local then rec = data_carried(rec, num, sk, ne, nm, kch) end
        if rec then
            rec.kind = kch
            if lim_hit then rec.limit = lim_hit end
        end
        return full and "full" or "delta", rec, list, d, dr_miss, ne, dr_tree_nm, now
    end

    -- State, first pass, a data frame the state writer's known paths do not take (state_data): its
    -- values one by one (data_values), then data_record.  (d.wl: see state_data.)
    local function data_general(pinfo, d, num, sk, cs_status, full_local, tree, list)
        if F.n_pos > 0 and list.by_length then list = frame_list(list) end
        d.wl = false
        local full, ne, nm, miss_n, full_l, rec_nm = data_values(d, list, num, sk, cs_status ~= 0, full_local,
            tree ~= nil)
        dr_ne, dr_nm, dr_miss, dr_tree_nm = ne, rec_nm, miss_n, nm
        -- a bare N in a positional direction with a journal: later passes must not ask the
        -- journal what it carried (state_later_pass)
        if F.nv == 0 and d.pos and d.hist then get_rec(num, sk, true).bare = true end
        return data_record(pinfo, d, num, sk, full, full_l, cs_status, list)
    end

    -- State, first pass, a known subset's delta (state_data) that has a table record: a late sync
    -- (its age: the time since its direction's last full frame, at now), or a carried value with a
    -- line break.  Returns state_data's answers.
    local function subset_record(d, num, sk, sub, list, nm, now)
        local rec = get_rec(num, sk, true)
        local age = now - (d.lastfull or d.first)
        if age > cfg.sync then rec.late = age end
        carried_record(rec, 0, nm > 0 and nm or carried_subset(d, sub.names))
        rec.kind = "d"
        return "delta", rec, list, d, sub.n, 0, nm, now
    end

    -- The first list declared with the content (names and types) of list (issue 44): the one a
    -- direction's history keeps (d.uhist, list_in_use), so a declaration repeated before every
    -- data frame keeps one list, not a copy each.  (The list itself stays a table of its own: a
    -- declaration replaces its direction's list, and what it keeps, even with the same names, as
    -- the Python twin's VarSource does.)
    local function canonical_list(list, types, n)
        local parts = {}
        for k = 1, n do parts[k] = list[k] .. "\0" .. (types[k] or "") end
        local key = table.concat(parts, "\1")
        local canon = decl_lists[key]
        if not canon then canon = list; decl_lists[key] = list end
        return canon
    end

    -- State, first pass, a declaration with a good checksum: the list it declares (a list learnt
    -- from a declaration: past its end var.unknown).  An N declaration is its own conversation's
    -- list; an L one the inbound list of the declarer's receiver (the declaration's destination
    -- address to the declarer's, letters reversed, whatever the ports).  Either is its letter
    -- pair's latest.  docs/fields-sharedlink.md, "Lists by receiver".
    local function learn_declaration(pinfo, num, dstb, srcb, dst, src)
        local l_ord, n_ord = F.l_ord, F.n_ord
        local dd, rkey, rl, base_list
        if l_ord then
            rl = dst .. src
            rkey = rev_akey(pinfo) .. "|" .. rl
            base_list = source_list(rkey, rl)
        else
            rl = src .. dst
            dd = get_dir(pinfo, num, dstb, srcb)
            base_list = dd.list or source_list((dd.akey or "") .. "|" .. rl, rl)
        end
        local newlist = {}
        local types = {}
        newlist.t, newlist.decl = types, true
        local start = l_ord or n_ord or 0
        for k = 1, math.min(start, #base_list) do
            newlist[k] = base_list[k]
            types[k] = base_list.t and base_list.t[k]
        end
        local maxi = #newlist
        for v = 1, F.nv do
            if VN[v] and VI[v] < LIM.max_slots then
                newlist[VI[v] + 1] = VN[v]
                types[VI[v] + 1] = VT[v] and valid_type(VT[v]) or nil
                if VI[v] + 1 > maxi then maxi = VI[v] + 1 end
            end
        end
        for k = 1, maxi do newlist[k] = slot_name(newlist, k - 1) end
        newlist.canon = canonical_list(newlist, types, maxi)
        if dd then
            dd.list = newlist
        elseif inbound[rkey] or ninbound < LIM.max_conversations then
            if not inbound[rkey] then ninbound = ninbound + 1 end
            inbound[rkey] = newlist
        else
            lim_hit = "Limit exceeded: more than " .. LIM.max_conversations ..
                " receivers with an inbound list (max_conversations)"
        end
        pair_lists[rl] = newlist
        lists_gen = lists_gen + 1
    end

    -- A query waits for its reply (under its ask key and each name it asks for; at most
    -- max_pending a querier, at most max_conversations queriers (a new one past them is refused,
    -- as Python's PendingAsks does, issue 40), max_pending_total in all (issue 44).
    local function ask(ak, name, rec)
        local qkey = ak .. ":" .. name
        if pending_q[qkey] then
            pending_q[qkey] = rec
        elseif LIM.npend[ak] == nil and LIM.nqueriers >= LIM.max_conversations then
            lim_hit = "Limit exceeded: more than " .. LIM.max_conversations ..
                " queriers with unanswered queries (max_conversations)"
        elseif (LIM.npend[ak] or 0) >= LIM.max_pending then
            lim_hit = "Limit exceeded: more than " .. LIM.max_pending ..
                " unanswered queries in this conversation (max_pending)"
        elseif LIM.npend_total >= LIM.max_pending_total then
            lim_hit = "Limit exceeded: more than " .. LIM.max_pending_total ..
                " unanswered queries in all (max_pending_total)"
        else
            if LIM.npend[ak] == nil then LIM.nqueriers = LIM.nqueriers + 1 end
            pending_q[qkey] = rec
            LIM.npend[ak] = (LIM.npend[ak] or 0) + 1
            LIM.npend_total = LIM.npend_total + 1
        end
    end

    -- The query that asked (answer key ak, name) answered: its record, taken off, or nil.
    local function answered(ak, name)
        local qkey = ak .. ":" .. name
        local qrec = pending_q[qkey]
        if qrec then
            pending_q[qkey] = nil
            LIM.npend[ak] = (LIM.npend[ak] or 1) - 1
            LIM.npend_total = LIM.npend_total - 1
        end
        return qrec
    end

    -- A list request (L? or N?) and the declaration that answers it (L? the N list, N? the L list).
    local function link_list_request(pinfo, num, sk, kind, rec, qk, ak)
        if kind == "query" and F.nq == 0 then
            rec = rec or get_rec(num, sk, true)
            rec.num, rec.t = num, pinfo.rel_ts
            ask(qk, F.l_ord and "#N" or "#L", rec)
        elseif kind == "declaration" then
            local qrec = answered(ak, F.l_ord and "#L" or "#N")
            if qrec then
                rec = rec or get_rec(num, sk, true)
                qrec.req_in, rec.req_to, rec.req_rt = num, qrec.num, pinfo.rel_ts - qrec.t
            end
        end
        return rec
    end

    -- State, first pass: a query or declaration waits for its reply; a reply finds its query
    -- (docs/fields-sharedlink.md, "Replies").
    local function link_query_reply(pinfo, num, sk, kind, dst, src, rec)
        local qk, ak = ask_keys(pinfo, src, dst)
        if kind ~= "reply" then rec = link_list_request(pinfo, num, sk, kind, rec, qk, ak) end
        for v = 1, F.nv do
            local name = VN[v]
            if name then
                if VR[v] then
                    rec = rec or get_rec(num, sk, true)
                    local qrec = answered(ak, name)
                    if qrec then
                        qrec.resp_in = qrec.resp_in or {}
                        qrec.resp_in[name] = num
                        rec.resp_to = rec.resp_to or {}
                        rec.resp_to[name] = qrec.num
                        rec.rt = rec.rt or {}
                        rec.rt[name] = pinfo.rel_ts - qrec.t
                    else
                        rec.unmatched = rec.unmatched or {}
                        rec.unmatched[name] = true
                    end
                elseif kind ~= "reply" then
                    rec = rec or get_rec(num, sk, true)
                    rec.num = num
                    rec.t = pinfo.rel_ts
                    ask(qk, name, rec)
                end
            end
        end
        return rec
    end

    -- The list in use in direction d (src to dst: the address bytes); when it changes, the change
    -- is remembered (read back on later passes: list_at).  Kept in d.lcur while d.lgen is lists_gen
    -- (speed trick, measured: a data frame reads two fields, see state_data).
    local function list_in_use(d, num, sk, dstb, srcb)
        local list = d.list
        if not list then
            local rkey = d.rkey   -- its receiver's key: addresses, "|", letters src .. dst (made once)
            if not rkey then
                d.letters = LETTER[srcb] .. LETTER[dstb]
                rkey = (d.akey or "") .. "|" .. d.letters
                d.rkey = rkey
            end
            list = inbound[rkey] or pair_lists[d.letters] or cfg.pairs[d.letters] or cfg.list
        end
        local old = d.used_list or cfg.list
        if list ~= old then
            -- the history keeps a declared list's canonical copy, once a run (issue 44)
            local h, canon = d.uhist, list.canon or list
            if not h then h = {}; d.uhist = h end
            local nh = #h
            if nh == 0 or h[nh] ~= canon then
                h[nh + 1], h[nh + 2], h[nh + 3] = num, sk, canon
            end
            d.used_list = list
            replace_values(d, old, list)
        end
        d.lcur, d.lgen = list, lists_gen
        return list
    end

    local LINKED = { query = true, reply = true, declaration = true }   -- kinds a query/reply link concerns

    -- The frame's record with the limit it hit (lim_hit), if any.
    local function limit_record(rec, num, sk)
        if lim_hit then
            rec = rec or get_rec(num, sk, true)
            rec.limit = lim_hit
        end
        return rec
    end

    -- The limit text of a direction past max_conversations.
    local function over_text()
        return "Limit exceeded: more than " .. LIM.max_conversations .. " directions with state" ..
            " (max_conversations); this one keeps none"
    end

    -- State on the first pass, a frame of another kind than data between nodes A-P (malformed,
    -- reply, query, declaration, command..., or a data frame whose addresses are not nodes A-P:
    -- kind nil, full or delta as full_local tells; addrs_ok: both addresses are nodes A-P).  Returns
    -- the kind, the record (nil: none), the list in use, the direction state (malformed, reply),
    -- and 0, 0, 0 (as state_data's).  The arguments are state_data's; the frame record tells the
    -- kind the fields tell (F.fkind: fields_facts) and addrs_ok.
    function state_other(pinfo, num, sk, cs_status, dstb, srcb, full_local)
        local kind, addrs_ok = F.fkind, F.addrs_ok
        local good = cs_status ~= 0
        lim_hit = false
        local rec, list, d = nil, cfg.list, nil
        if not kind then kind = full_local and "full" or "delta" end   -- a data frame, addresses not A-P
        if not addrs_ok then return kind, nil, list, nil, 0, 0, 0 end
        if kind == "malformed" or kind == "reply" then
            d = get_dir(pinfo, num, dstb, srcb)
            if d.over then lim_hit = over_text() end
            list = frame_list(list_in_use(d, num, sk, dstb, srcb))
        elseif kind == "declaration" and good then
            learn_declaration(pinfo, num, dstb, srcb, LETTER[dstb], LETTER[srcb])
        end
        if LINKED[kind] and good then
            rec = link_query_reply(pinfo, num, sk, kind, LETTER[dstb], LETTER[srcb], rec)
        end
        return kind, limit_record(rec, num, sk), list, d, 0, 0, 0
    end

    -- The list in use in direction d on a data frame when d.lcur may not be it (d.lgen is not
    -- lists_gen): list_in_use's; a direction past max_conversations (made anew each frame, so it
    -- always comes here) gets the limit's text.
    local function data_list(d, num, sk, dstb, srcb)
        if d.over then lim_hit = over_text() end
        return list_in_use(d, num, sk, dstb, srcb)
    end

    -- State on the first pass, a data frame between nodes A-P (cs_status: its checksum verdict, 0
    -- bad; tree: nil when there is none).  Returns the kind, the record (nil: none), the list in
    -- use, the direction state, the named variables carried, ne/nm (see data_values) and the
    -- packet's time (pinfo.rel_ts, read once: link health takes it, health.lua's H.frame; the other
    -- writers read none and give nil).
    -- A named layout's frame with a good checksum has its values stored by the layout's code
    -- (the loop below) when its names are known ones (speed trick, measured: no data_values call):
    --  * the direction's whole known set (d.names_is; never a journal's, whose names outnumber any
    --    layout's), the commonest frame: nothing carried, only the sync clock changes (as
    --    sync_clock's: no data_record call with a dozen arguments);
    --  * a subset of them (known_subset), a compressed stream's delta: the sync clock, and the
    --    record, its carried names' line made from the direction (records.subset_line), kept in sub
    --    while d.wl, the layout whose values were stored last in the direction, is this one; a table
    --    record when the frame has one anyway (subset_record).  Neither meets a limit (lim_hit
    --    stays false): a direction past max_conversations (add_dir) is made anew each frame, with
    --    no names, and neither stores a new name.  A data frame with no value at all
    --    (NO_VALUES: [:AB|N0|C..], a compressed stream's delta when nothing changed) is taken as a
    --    layout of no names, so it carries them all; in a positional direction (d.pos) neither
    --    path is taken (known_subset gives none): data_general.
    -- Any other frame: data_general.
    function state_data(pinfo, num, sk, cs_status, dstb, srcb, full_local, tree)
        lim_hit = false
        local d = get_dir(pinfo, num, dstb, srcb)
        local list = d.lcur
        if d.lgen ~= lists_gen then list = data_list(d, num, sk, dstb, srcb) end
        local named = F.named or (F.nv == 0 and NO_VALUES)
        if cs_status == 0 or not named then
            return data_general(pinfo, d, num, sk, cs_status, full_local, tree, list)
        end
        local sub = nil
        if d.names_is ~= named then
            sub = (named.subs or NO_SUBSETS)[d]
            if not sub or sub.gen ~= d.sgen then sub = known_subset(d, named) end
            if not sub then return data_general(pinfo, d, num, sk, cs_status, full_local, tree, list) end
        end
        -- the layout's values (VV, in its names' order: known names) into the direction
        local vals, from, names = d.vals, d.from, named.N
        for k = 1, named.n do
            local name = names[k]
            vals[name], from[name] = VV[k], num
        end
        if not sub then
            d.wl = named
            if full_local then
                local now = g_rel_ts(pinfo)
                d.lastfull = now   -- (d.first, read only while there is none, not needed)
                return "full", nil, list, d, 0, 0, 0, now
            end
            dr_ne, dr_nm, dr_miss, dr_tree_nm = 0, 0, 0, 0
            return data_record(pinfo, d, num, sk, full_local, full_local, cs_status, list)
        end
        -- another layout's values were stored since sub's line was made: it is made again
        if d.wl ~= named then d.wl = named; sub.line, sub.run = false, false end
        local now = g_rel_ts(pinfo)
        local last = d.lastfull or d.first   -- (a delta: the sync clock as sync_clock's)
        if not last then last = now; d.first = now end
        local nm = 0
        if tree then nm = carried_subset(d, sub.names) end   -- MISS, for a tree only
        if now - last > cfg.sync or not subset_line(num, sk, sub, d) then
            return subset_record(d, num, sk, sub, list, nm, now)
        end
        return "delta", nil, list, d, sub.n, 0, nm, now
    end
end


-- The list in use at frame (num, sk) on the first pass, from the direction's history of changes.
-- The entries (num, sk, list) are in capture order: a binary search (linear time over a pass).
local function list_at(d, num, sk)
    local h = d.uhist
    if not h then return cfg.list end
    local lo, hi, found = 1, #h / 3, nil
    while lo <= hi do
        local mid = floor((lo + hi) / 2)
        local hn = h[3 * mid - 2]
        if hn < num or (hn == num and h[3 * mid - 1] <= sk) then found = mid; lo = mid + 1 else hi = mid - 1 end
    end
    return found and h[3 * found] or cfg.list
end

-- A later pass, a frame whose state needs its direction: the list in use there on the first pass
-- and, for a named frame the journal judged, what it carried (miss_n, nm), from the journal.
local function later_dir(pinfo, num, sk, is_data, dstb, srcb, has_tree, miss_n)
    local d = get_dir(pinfo, num, dstb, srcb)
    local list = frame_list(list_at(d, num, sk))
    local nm = 0
    if is_data and d.jkey and F.n_pos == 0 then
        local key = journal.key(num, sk)
        if key >= d.jkey then miss_n, nm = journal.missing(d, key, has_tree) end
    end
    return list, d, miss_n, nm
end

-- State on a later pass: the record, and the list in use at this frame on the first pass
-- (looked up only where it names something: positional values, or a tree to show indexes).  A
-- data frame's kind: the record's, else the verdict without state.  The arguments and answers are
-- state_other's (ne: 0).
-- A data frame's kind on a later pass: its record's, else full when full locally with nothing carried.
local function later_kind(rec, full_local, miss_n)
    local rk = rec and rec.kind
    if rk then return rk == "f" and "full" or "delta" end
    return (full_local and miss_n == 0) and "full" or "delta"
end

-- A frame whose direction only its tree needs (no positional value, no journal, not a reply): the
-- direction and list are found when the tree asks (later_tree_dir), not here: a hidden tree
-- nobody references a variable's field of never needs them (speed trick, measured: the GUI's rows).
local pend_pinfo, pend_num, pend_sk, pend_dstb, pend_srcb
local function later_tree_dir()
    local pinfo = pend_pinfo
    if not pinfo then return nil end
    pend_pinfo = nil
    local list, d = later_dir(pinfo, pend_num, pend_sk, false, pend_dstb, pend_srcb, true, 0)
    return list, d
end

local function state_later_pass(pinfo, num, sk, _, dstb, srcb, full_local, tree)
    local kind, is_data, addrs_ok = F.fkind, F.is_data, F.addrs_ok
    local has_tree = tree ~= nil
    local rec = get_rec(num, sk, false)
    local miss_n = (rec and rec.miss) and floor(#rec.miss / 3) or 0
    local nm, list, d = 0, cfg.list, nil
    pend_pinfo = nil
    if (is_data or kind == "malformed" or kind == "reply") and addrs_ok then
        if F.n_pos > 0 or LIM.journal or kind == "reply" then
            list, d, miss_n, nm = later_dir(pinfo, num, sk, is_data and not (rec and rec.bare), dstb, srcb, has_tree,
                miss_n)
        elseif has_tree then
            pend_pinfo, pend_num, pend_sk, pend_dstb, pend_srcb = pinfo, num, sk, dstb, srcb
        end
    end
    if is_data then kind = later_kind(rec, full_local, miss_n) end
    return kind, rec, list, d, miss_n, 0, nm
end

S.get_dir, S.list_at, S.journal, S.JOURNAL_NAMES = get_dir, list_at, journal, JOURNAL_NAMES
S.list_type, S.later_tree_dir = list_type, later_tree_dir
S.state_data, S.state_other, S.state_later_pass = state_data, state_other, state_later_pass
return S
