-- SharedLink dissector module: state, what a direction remembers (values, names, lists, the sync clock, pending
-- queries) and the one place that writes it on the first pass or reads it back on later ones.
-- Loaded by sharedlink.lua (load_module); Wireshark also runs every .lua file of a plugin folder's
-- subfolders as a plugin of its own: this file then does nothing.

local token, M = ...
if type(token) ~= "table" or token.sharedlink_module ~= true then return end

local U, cfg, wsapi, tostring = M.util, M.prefs, M.wsapi, tostring
local floor, valid_type, VT, VN = math.floor, U.valid_type, M.parse.P.VT, M.parse.P.VN
local VV, VI, VR = M.parse.P.VV, M.parse.P.VI, M.parse.P.VR

local P = M.parse.P
local R = M.records
local PG = wsapi.PG
local get_rec, carried_store, CARRY, MISS = R.get_rec, R.carried_store, R.CARRY, R.MISS

-- Per-capture state (reset by S.reset)
local dirs          -- direction key -> direction state
local pair_lists    -- "SD" letters -> learnt list
local pending_q     -- query key -> record of the query frame
local dir_cache_key, dir_cache_num, dir_cache_ports -- cache for the current packet
local last_asrc, last_adst, last_pdir, last_akey     -- addresses of the last packet and their key
local stamp_ctr = 0
local S = {}
function S.reset()
    dirs, pair_lists, pending_q = {}, {}, {}
    dir_cache_key, dir_cache_num, dir_cache_ports = nil, nil, 0
    last_asrc, last_adst, last_pdir, last_akey = nil, nil, nil, nil
end
S.reset()

------------------------------------------------------------------------------
-- Direction state
------------------------------------------------------------------------------
-- vals/from: name -> last good value / its frame; names: named variables in the order first
-- sent in a good frame, npos: name -> its index there, nfirst: name -> that frame;
-- seen: name -> stamp of the last frame that had it; maxslot: highest positional slot that
-- ever held a value; first/lastfull: times of the first frame and of the last good full one.
local function new_dir()
    return { vals = {}, from = {}, names = {}, npos = {}, nfirst = {}, nkey = {}, seen = {}, maxslot = -1,
        first = nil, lastfull = nil, list = nil }
end

-- Direction state for (src address, dst address, src port, dst port, letters).
-- dirs[addresses][ports and letters as one number]; cheap on the per-frame path.
local function get_dir(pinfo, num, dstb, srcb)
    local byaddr
    if dir_cache_num == num then
        byaddr = dir_cache_key
    else
        -- the capture direction keeps the two directions of a serial line apart.  Speed
        -- trick (measured): Address objects compare cheaper than they print, so the key
        -- text is rebuilt only when the addresses differ from the previous packet's.
        local pg = PG
        local sport, dport = pg.src_port(pinfo), pg.dst_port(pinfo)
        -- the capture direction only where no port tells the directions apart (a serial line);
        -- a UDP/TCP flow is one direction whatever direction flags its link layer had
        local asrc, adst = pg.src(pinfo), pg.dst(pinfo)
        local pdir = (sport == 0 and dport == 0) and pg.p2p_dir(pinfo) or -1
        local akey
        if pdir == last_pdir and asrc == last_asrc and adst == last_adst then
            akey = last_akey
        else
            akey = tostring(asrc) .. ">" .. tostring(adst) .. "/" .. pdir
            last_asrc, last_adst, last_pdir, last_akey = asrc, adst, pdir, akey
        end
        byaddr = dirs[akey]
        if not byaddr then
            byaddr = {}
            dirs[akey] = byaddr
        end
        dir_cache_key = byaddr
        dir_cache_num = num
        dir_cache_ports = (sport * 65536 + dport) * 65536
    end
    local key = dir_cache_ports + dstb * 256 + srcb
    local d = byaddr[key]
    if not d then
        d = new_dir()
        if cfg.LIM.ndirs >= cfg.LIM.max_conversations then d.over = true; return d end   -- kept nowhere
        cfg.LIM.ndirs = cfg.LIM.ndirs + 1
        byaddr[key] = d
    end
    return d
end

-- The same for the reverse direction (dst -> src) of the current packet.
local function get_rev_dir(pinfo, dstb, srcb)
    local sport, dport = pinfo.src_port, pinfo.dst_port
    local pd = -1
    if sport == 0 and dport == 0 then
        pd = pinfo.p2p_dir
        if pd == 0 or pd == 1 then pd = 1 - pd end
    end
    local akey = tostring(pinfo.dst) .. ">" .. tostring(pinfo.src) .. "/" .. pd
    local byaddr = dirs[akey]
    if not byaddr then
        byaddr = {}
        dirs[akey] = byaddr
    end
    local key = (dport * 65536 + sport) * 65536 + srcb * 256 + dstb
    local d = byaddr[key]
    if not d then
        d = new_dir()
        if cfg.LIM.ndirs >= cfg.LIM.max_conversations then d.over = true; return d end   -- kept nowhere
        cfg.LIM.ndirs = cfg.LIM.ndirs + 1
        byaddr[key] = d
    end
    return d
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
        cfg.LIM.journal = true
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
        for v = 1, P.nv do
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

-- state_first_pass and its helpers (a block, as parse_frame)
local state_first_pass
do
    -- State, first pass, a data frame: its values go into the direction's state (good checksum),
    -- what it leaves out is gathered in CARRY (empty D fields: value, frame, ...; ne entries) and
    -- MISS (named variables: name, value, frame, ...; nm entries).  Returns whether it is full,
    -- ne, nm, the number of named variables carried, and full_local (the verdict without state).
    local function data_values(d, list, num, sk, good, full_local, has_tree)
        local fast_sh, n_pos, nd, n_ord = P.fast_sh, P.n_pos, P.nd, P.n_ord
        local ne, nm, miss_n = 0, 0, 0
        local full
        local hist, key = d.hist, nil
        if hist or #d.names > JOURNAL_NAMES then
            key = journal.key(num, sk)
            if not hist and not d.over then hist = journal.start(d, key) end
        end
        if good and fast_sh and d.names_is == fast_sh.N and not hist then
            -- same layout as the known variable set: nothing can be missing
            local vals, from = d.vals, d.from
            for v = 1, P.nv do
                local name = VN[v]
                vals[name] = VV[v]
                from[name] = num
            end
            full = full_local
        else
            local vals, from, seen = d.vals, d.from, d.seen
            local names = d.names
            stamp_ctr = stamp_ctr + 1
            local stamp = stamp_ctr
            local required_missing = false   -- a slot that held a value is empty here
            local maxslot = -1
            local present = 0                -- known names present (distinct)
            local max_slots = cfg.LIM.max_slots
            ne = 0
            for v = 1, P.nv do
                local val = VV[v]
                if val then
                    local name = VN[v]
                    if name then
                        local st = seen[name]
                        if not st and good then
                            if #names < cfg.LIM.max_names then
                                names[#names + 1] = name
                                d.npos[name] = #names - 1
                                d.nfirst[name] = num
                                d.nkey[#names] = key or journal.key(num, sk)
                                d.names_is = nil
                                st = 0
                            else
                                -- a new name past max_names: no state
                                cfg.LIM.hit = "Limit exceeded: more than " .. cfg.LIM.max_names ..
                                    " names in this direction (max_names)"
                            end
                        end
                        if st then
                            if good then
                                vals[name] = val
                                from[name] = num
                                if hist then journal.set(hist, name, key, val) end
                            end
                            if st ~= stamp then present = present + 1; seen[name] = stamp end
                        end
                    elseif VI[v] < max_slots then
                        local slot = VI[v]
                        name = list[slot + 1] or ("#" .. slot)
                        if slot > maxslot then maxslot = slot end
                        if val == "" then
                            local cv = vals[name]
                            if cv then required_missing = true end
                            CARRY[ne + 1] = cv or false
                            CARRY[ne + 2] = from[name] or false
                            ne = ne + 2
                        elseif good then
                            vals[name] = val
                            from[name] = num
                            if slot > d.maxslot then d.maxslot = slot end
                        end
                    end
                end
            end
            -- positional: required slots past the frame's last D
            if n_pos > 0 then
                for slot = maxslot + 1, d.maxslot do
                    if vals[list[slot + 1] or ("#" .. slot)] then required_missing = true; break end
                end
            end
            -- named: known variables missing from this frame (a journal: counted; listed only
            -- for a tree, kept in no record)
            if n_pos == 0 and #names > 0 and hist then
                miss_n = #names - present
                if has_tree then
                    for k = 1, #names do
                        local name = names[k]
                        if seen[name] ~= stamp then
                            MISS[nm + 1], MISS[nm + 2], MISS[nm + 3] = name, vals[name] or false, from[name] or false
                            nm = nm + 3
                        end
                    end
                end
            elseif n_pos == 0 and #names > 0 then
                for k = 1, #names do
                    local name = names[k]
                    if seen[name] ~= stamp then
                        MISS[nm + 1], MISS[nm + 2], MISS[nm + 3] = name, vals[name] or false, from[name] or false
                        nm = nm + 3
                        miss_n = miss_n + 1
                    end
                end
            end
            if fast_sh and good and miss_n == 0 and #names == fast_sh.n then d.names_is = fast_sh.N end
            full = nd > 0 and (n_ord == nil or n_ord == 0) and not required_missing and miss_n == 0
            if n_pos == 0 then full_local = full_local and miss_n == 0 end
        end
        return full, ne, nm, miss_n, full_local, hist ~= nil
    end

    -- State, first pass, a data frame: the sync clock, and the record later passes read (late
    -- sync, carried values, a kind the fields alone do not tell).  Returns the record and kind.
    local function data_record(pinfo, d, num, sk, full, full_local, good, ne, nm)
        local rec = cfg.LIM.hit and get_rec(num, sk, true) or nil   -- a limit's expert: a table record
        local kind
        local now = pinfo.rel_ts
        local first = d.first
        if not first then first = now; d.first = now end
        if full then
            if good then d.lastfull = now end
        else
            local age = now - (d.lastfull or first)
            if age > cfg.sync then
                rec = rec or get_rec(num, sk, true)
                rec.late = age
            end
        end
        local kch = full and "f" or "d"
        -- carried values of empty D fields: a packed text record unless the
        -- frame has a table record anyway
        if ne > 0 or nm > 0 then
            if rec or not carried_store(num, sk, ne, nm, kch) then
                rec = rec or get_rec(num, sk, true)
                for k = 1, ne do rec[k] = CARRY[k] end
                if nm > 0 then
                    local miss = {}
                    for k = 1, nm do miss[k] = MISS[k] end
                    rec.miss = miss
                end
            end
        elseif full ~= full_local then
            rec = rec or get_rec(num, sk, true)
        end
        if rec then rec.kind = kch end
        kind = full and "full" or "delta"
        return rec, kind
    end

    -- State, first pass, a declaration with a good checksum: the list it declares.
    local function learn_declaration(pinfo, num, dstb, srcb, dst, src, letters)
        local l_ord, n_ord = P.l_ord, P.n_ord
        local dd, rl
        if l_ord then
            -- the sender's inbound list = the list used from dst to src
            dd = get_rev_dir(pinfo, dstb, srcb)
            rl = dst .. src
        else
            dd = get_dir(pinfo, num, dstb, srcb)
            rl = letters
        end
        local base_list = dd.list or pair_lists[rl] or cfg.list
        local newlist = {}
        local types = {}
        newlist.t = types
        local start = l_ord or n_ord or 0
        for k = 1, math.min(start, #base_list) do
            newlist[k] = base_list[k]
            types[k] = base_list.t and base_list.t[k]
        end
        local maxi = #newlist
        for v = 1, P.nv do
            if VN[v] and VI[v] < cfg.LIM.max_slots then
                newlist[VI[v] + 1] = VN[v]
                types[VI[v] + 1] = VT[v] and valid_type(VT[v]) or nil
                if VI[v] + 1 > maxi then maxi = VI[v] + 1 end
            end
        end
        for k = 1, maxi do newlist[k] = newlist[k] or ("#" .. (k - 1)) end
        dd.list = newlist
        pair_lists[rl] = newlist
    end

    -- State, first pass: a query or declaration waits for its reply; a reply finds its query.
    local function link_query_reply(pinfo, num, sk, kind, dst, src, rec)
        local pa, pb = pinfo.src_port, pinfo.dst_port
        if pa > pb then pa, pb = pb, pa end
        local ports = ":" .. pa .. "-" .. pb
        for v = 1, P.nv do
            local name = VN[v]
            if name then
                if VR[v] then
                    rec = rec or get_rec(num, sk, true)
                    local qkey = dst .. ">" .. src .. ":" .. name .. ports
                    local qrec = pending_q[qkey]
                    if qrec then
                        pending_q[qkey] = nil
                        local ck = dst .. ">" .. src .. ports
                        cfg.LIM.npend[ck] = (cfg.LIM.npend[ck] or 1) - 1
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
                    local qkey, ck = src .. ">" .. dst .. ":" .. name .. ports, src .. ">" .. dst .. ports
                    if pending_q[qkey] then
                        pending_q[qkey] = rec
                    elseif (cfg.LIM.npend[ck] or 0) < cfg.LIM.max_pending then
                        pending_q[qkey] = rec
                        cfg.LIM.npend[ck] = (cfg.LIM.npend[ck] or 0) + 1
                    else
                        cfg.LIM.hit = "Limit exceeded: more than " .. cfg.LIM.max_pending ..
                            " unanswered queries in this conversation (max_pending)"
                    end
                end
            end
        end
        return rec
    end

    -- State on the first pass.  Returns the kind, the record (nil: none), the list in use, the
    -- direction state (data frames), the named variables carried, and ne/nm (see data_values).
    function state_first_pass(pinfo, num, sk, kind, is_data, good, dstb, srcb, dst, src, addrs_ok, full_local,
                              has_tree)
        local rec, list, d = nil, cfg.list, nil
        local miss_n, ne, nm = 0, 0, 0
        cfg.LIM.hit = false
        local letters = src .. dst
        if (is_data or kind == "malformed") and addrs_ok then
            d = get_dir(pinfo, num, dstb, srcb)
            if d.over then
                cfg.LIM.hit = "Limit exceeded: more than " .. cfg.LIM.max_conversations .. " directions with state" ..
                    " (max_conversations); this one keeps none"
            end
            list = d.list or pair_lists[letters] or cfg.list
            -- remember when the list in use changes (read back on later passes)
            if list ~= (d.used_list or cfg.list) then
                local h = d.uhist
                if not h then h = {}; d.uhist = h end
                h[#h + 1] = num
                h[#h + 1] = sk
                h[#h + 1] = list
                d.used_list = list
            end
            if is_data then
                local full, journaled
                full, ne, nm, miss_n, full_local, journaled = data_values(d, list, num, sk, good, full_local, has_tree)
                -- a journal's carried names go in no record (see journal)
                rec, kind = data_record(pinfo, d, num, sk, full, full_local, good, ne, journaled and 0 or nm)
            end
        elseif kind == "declaration" and addrs_ok and good then
            learn_declaration(pinfo, num, dstb, srcb, dst, src, letters)
        end
        if (kind == "query" or kind == "reply" or kind == "declaration") and addrs_ok and good then
            rec = link_query_reply(pinfo, num, sk, kind, dst, src, rec)
        end
        if cfg.LIM.hit then
            rec = rec or get_rec(num, sk, true)
            rec.limit = cfg.LIM.hit
        end
        return kind, rec, list, d, miss_n, ne, nm
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

-- State on a later pass: the record, and the list in use at this frame on the first pass
-- (looked up only where it names something: positional values, or a tree to show indexes).
local function state_later_pass(pinfo, num, sk, kind, is_data, dstb, srcb, addrs_ok, full_local, has_tree)
    local rec = get_rec(num, sk, false)
    local miss_n = (rec and rec.miss) and floor(#rec.miss / 3) or 0
    local nm = 0
    local list, d = cfg.list, nil
    if (is_data or kind == "malformed") and addrs_ok and (has_tree or P.n_pos > 0 or cfg.LIM.journal) then
        d = get_dir(pinfo, num, dstb, srcb)
        list = list_at(d, num, sk)
        -- a named frame the journal judged: what it carried, from the journal
        if is_data and d.jkey and P.n_pos == 0 then
            local key = journal.key(num, sk)
            if key >= d.jkey then miss_n, nm = journal.missing(d, key, has_tree) end
        end
    end
    if is_data then
        if rec and rec.kind then
            kind = rec.kind == "f" and "full" or "delta"
        else
            kind = (full_local and miss_n == 0) and "full" or "delta"
        end
    end
    return kind, rec, list, d, miss_n, nm
end

S.get_dir, S.list_at, S.journal, S.JOURNAL_NAMES = get_dir, list_at, journal, JOURNAL_NAMES
S.state_first_pass, S.state_later_pass = state_first_pass, state_later_pass
-- the list learnt for a letter pair (the express lane)
function S.pair_list(letters) return pair_lists[letters] end
return S
