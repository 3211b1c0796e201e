-- SharedLink dissector module: express, the express lane (see express).
-- Loaded by sharedlink.lua (load_module); Wireshark also runs every .lua file of a plugin folder's
-- subfolders as a plugin of its own: this file then does nothing.

local token, M = ...
if type(token) ~= "table" or token.sharedlink_module ~= true then return end

local U, cfg, wsapi, sl = M.util, M.prefs, M.wsapi, M.proto
local s_byte, s_find, s_match, floor = string.byte, string.find, string.match, math.floor
local INFO_MAX, B_RBRACK, B_CR, B_LF = U.INFO_MAX, U.B_RBRACK, U.B_CR, U.B_LF
local parse_long, checksum_value, HEXV, VT = U.parse_long, U.checksum_value, U.HEXV, M.parse.P.VT
local VN, VV, VI, VR = M.parse.P.VN, M.parse.P.VV, M.parse.P.VI, M.parse.P.VR

local P = M.parse.P
local R, S, T, Pm = M.records, M.state, M.tree, M.parse
local LY, MARKS, fast_positions = Pm.LY, Pm.MARKS, Pm.fast_positions
local PG, TI = wsapi.PG, wsapi.TI
local get_rec, sk_text, from_text, carried_line_end = R.get_rec, R.sk_text, R.from_text, R.carried_line_end
local MISS = R.MISS
local get_dir, list_at, journal, JOURNAL_NAMES = S.get_dir, S.list_at, S.journal, S.JOURNAL_NAMES
local tree_compact_frame, tree_full = T.tree_compact_frame, T.tree_full

-- Express lane (speed trick, measured: the summary pass 10 us a frame faster, a compressed
-- stream's 20): in any pass (no tree, one nobody sees, a shown one), a packet that is one plain
-- named frame of a layout its node pair sent before, with a good checksum and N0, whose
-- variables the direction knows already -- the bulk of a beacon stream, full or compressed -- is
-- decoded here in one go.  It leaves the same state, records, Info and tree as the phases of
-- dissect_frame (parse_fast_named; data_values' known-set case, or its general case with
-- carried variables; data_record; info_frame's one concatenation; tree_compact_frame or
-- tree_full); anything else returns false before changing any state, and the phases take the
-- packet.  SHAREDLINK_NO_EXPRESS=1 turns it off; the tests compare both ways.
local EXPRESS = not wsapi.env.no_express
local NO_SHAPES = {}
local XSK = {}            -- frame key -> "|sk|d|0" (a line's text after its frame number)
local CARRIED_TAIL = {}   -- n -> " (+n carried)"
for k = 1, 64 do CARRIED_TAIL[k] = " (+" .. k .. " carried)" end

-- The direction's known variables a layout leaves out (nil: it names one the direction does not
-- know yet, or leaves none out), kept per layout until the direction learns another variable.
local function express_missing(d, sh)
    local npos, names, sn = d.npos, d.names, sh.N
    local in_layout = {}
    for k = 1, sh.n do
        if not npos[sn[k]] then return nil end
        in_layout[sn[k]] = true
    end
    local miss = {}
    for k = 1, #names do
        if not in_layout[names[k]] then
            -- a line break in a name: no record line (the phases make a table record)
            if s_find(names[k], "\n", 1, true) then return nil end
            miss[#miss + 1] = names[k]
        end
    end
    if #miss == 0 or not CARRIED_TAIL[#miss] then return nil end
    local xm = { count = #names, names = miss, tail = CARRIED_TAIL[#miss] }
    local cache = d.xmiss
    if not cache then cache = {}; d.xmiss = cache end
    cache[sh] = xm
    return xm
end

-- With no tree, whether the express lane's frame is one whose tree has no expert info: its line
-- ends in CR LF, its checksum is two upper-case hex digits, every value matches its type.  A
-- frame that has one goes to the phases (dissect_frame reports it).
local express_plain
do
    local UHEX = {}
    for t in pairs(HEXV) do
        if not s_find(t, "[a-f]") then UHEX[t] = true end
    end
    -- a double's value matched XDOUBLE already (see learn_named_shape)
    local function value_ok(vtype, v)
        if vtype == 0 then return v == nil or parse_long(v) ~= nil end
        return true
    end
    function express_plain(s, n, sh, ctext, c1, c2, c3, c4, c5, c6, c7, c8)
        if not UHEX[ctext] or s_byte(s, n) ~= B_LF or s_byte(s, n - 1) ~= B_CR or s_byte(s, n - 2) ~= B_RBRACK then
            return false
        end
        local tv = sh.TV
        if not tv then return true end
        return value_ok(tv[1], c1) and value_ok(tv[2], c2) and value_ok(tv[3], c3) and value_ok(tv[4], c4)
            and value_ok(tv[5], c5) and value_ok(tv[6], c6) and value_ok(tv[7], c7) and value_ok(tv[8], c8)
    end
end

local function express(s, n, tvb, pinfo, tree, cols, vis)
    local dstb, srcb = s_byte(s, 3, 4)
    local key = (dstb or 0) * 256 + (srcb or 0)
    -- the layout that matched a payload of this length last (a payload matches one layout at
    -- most), else the node pair's recent layouts, newest first.  Speed trick (measured): a
    -- compressed stream interleaves layouts of one prefix, and a pattern that fails late costs
    -- most of a match
    local lk = key * 65536 + n
    local sh, c1, c2, c3, c4, c5, c6, c7, c8, c9 = LY.xlen[lk]
    -- xhead: the layout's text up to its first value, found as plain text (speed trick,
    -- measured: a pattern matches text one character at a time); xpat: the rest, from there
    if sh and s_find(s, sh.xhead, 1, true) == 1 then
        c1, c2, c3, c4, c5, c6, c7, c8, c9 = s_match(s, sh.xpat, #sh.xhead + 1)
    end
    if not c1 then
        local mru = LY.named[key] or NO_SHAPES
        for k = 1, #mru do
            sh = mru[k]
            if s_find(s, sh.xhead, 1, true) == 1 then
                c1, c2, c3, c4, c5, c6, c7, c8, c9 = s_match(s, sh.xpat, #sh.xhead + 1)
            end
            if c1 then
                if k > 1 then table.remove(mru, k); table.insert(mru, 1, sh) end
                break
            end
        end
        if not c1 then
            sh = LY.bare[key]
            if not sh then return false end
            if s_find(s, sh.xhead, 1, true) == 1 then c1 = s_match(s, sh.xpat, #sh.xhead + 1) end
            if not c1 then return false end
        end
        if LY.xlen_n >= 4096 then LY.xlen, LY.xlen_n = {}, 0 end
        if n < 65536 then LY.xlen[lk], LY.xlen_n = sh, LY.xlen_n + 1 end
    end
    if sh.ord ~= 0 then return false end
    local total, sum, ctext = sh.sums(c1, c2, c3, c4, c5, c6, c7, c8, c9)
    if not total or total + sh.info_len > INFO_MAX then return false end
    if cfg.validate and HEXV[ctext] ~= (sh.fixed + sum) % 256 then return false end
    if not tree and not express_plain(s, n, sh, ctext, c1, c2, c3, c4, c5, c6, c7, c8) then return false end
    local pg = PG
    local num = pg.number(pinfo)
    local visited = pg.visited(pinfo)
    local sk = n * 1048576 + 1   -- the frame's key in its packet, as dissect makes it (sk_base + 1)
    local tail = nil    -- a delta's " (+n carried)"
    local d, list, rec, nm = nil, cfg.list, nil, 0   -- for the tree: see state_first_pass
    if visited then
        -- a later pass: no record means the first pass found it full; a carried-only record, a delta
        rec = get_rec(num, sk, false)
        if not rec and sh.bare then return false end   -- a bare frame with no record: the phases say why
        if cfg.LIM.journal then
            -- a frame the journal judged: the phases
            d = get_dir(pinfo, num, dstb, srcb)
            if d.jkey and journal.key(num, sk) >= d.jkey then return false end
        end
        if rec then
            if rec.late or rec[1] or rec.kind ~= "d" or not rec.miss then return false end
            tail = CARRIED_TAIL[floor(#rec.miss / 3)]
            if not tail or total + sh.dinfo_len + #tail > INFO_MAX then return false end
        end
        if tree then
            -- as state_later_pass: the list in use here on the first pass
            d = get_dir(pinfo, num, dstb, srcb)
            list = list_at(d, num, sk)
        end
    else
        d = get_dir(pinfo, num, dstb, srcb)
        if d.hist or d.over or #d.names >= JOURNAL_NAMES then return false end   -- a journal, a limit: the phases
        list = d.list or S.pair_list(sh.letters) or cfg.list
        if list ~= (d.used_list or cfg.list) then return false end
        local names, vals, from = sh.N, d.vals, d.from
        local now = pg.rel_ts(pinfo)
        local first = d.first
        if not first then first = now; d.first = now end
        if d.names_is == names then
            d.lastfull = now
        else
            -- a delta: the direction's other variables are carried forward
            local xm = d.xmiss and d.xmiss[sh]
            if not xm or xm.count ~= #d.names then
                xm = express_missing(d, sh)
                if not xm then return false end
            end
            tail = xm.tail
            local miss_names = xm.names
            -- no full frame for too long: the phases record the late sync
            if now - (d.lastfull or first) > cfg.sync then return false end
            if total + sh.dinfo_len + #tail > INFO_MAX then return false end
            -- the record line carried_store would write (num|sk|d|0|name|=value|frame|...), as
            -- pieces: no string is made for it until its chunk, and each carried variable's
            -- "|name|=value|frame" is kept in the direction (ctext) while its value and frame
            -- stay the same.  A value with a line break cannot go in a line (the phases make a
            -- table record).
            local ct, cfrom, cval = d.ctext, d.cfrom, d.cval
            if not ct then ct, cfrom, cval = {}, {}, {}; d.ctext, d.cfrom, d.cval = ct, cfrom, cval end
            local xsk = XSK[sk]
            if not xsk then xsk = "|" .. sk_text(sk) .. "|d|0"; XSK[sk] = xsk end
            local pend, i = R.pending()
            pend[i + 1], pend[i + 2] = num, xsk
            i = i + 2
            for k = 1, #miss_names do
                local name = miss_names[k]
                local f, v = from[name] or false, vals[name] or false
                local t = ct[name]
                if cfrom[name] ~= f or cval[name] ~= v or not t then
                    if v and s_find(v, "\n", 1, true) then return false end
                    t = "|" .. name .. (v and ("|=" .. v) or "|") .. "|" .. from_text(f)
                    ct[name], cfrom[name], cval[name] = t, f, v
                end
                pend[i + k] = t
                -- MISS, as data_values gathers it, for the tree (carried variables)
                if tree then MISS[nm + 1], MISS[nm + 2], MISS[nm + 3] = name, v, f; nm = nm + 3 end
            end
            i = i + #miss_names + 1
            pend[i] = "\n"
            carried_line_end(num, i)
        end
        sh.xstore(vals, from, num, c1, c2, c3, c4, c5, c6, c7, c8)
    end
    local info
    if tail then
        info = sh.xdinfo(c1, c2, c3, c4, c5, c6, c7, c8) .. tail
    else
        info = sh.xinfo(c1, c2, c3, c4, c5, c6, c7, c8)
    end
    if MARKS.express then info = MARKS.express .. info end
    cols.info = info
    if tree then
        -- the tree dissect_frame makes, from what parse_fast_named would have left: the compact
        -- one for a tree nobody sees (-Y, coloring rules, taps), else the full one
        VV[1], VV[2], VV[3], VV[4], VV[5], VV[6], VV[7], VV[8] = c1, c2, c3, c4, c5, c6, c7, c8
        local st, sn = sh.T, sh.N
        local nvals = sh.n
        for k = 1, nvals do VT[k], VN[k], VI[k], VR[k] = st[k], sn[k], k - 1, false end
        P.nv, P.ctext, P.n_ord, P.fast_sh = nvals, ctext, 0, sh
        local fl = n   -- the index of its ']': the pattern lets CR LF, CR or LF follow
        while s_byte(s, fl) ~= B_RBRACK do fl = fl - 1 end
        local cs_val, cs_calc, cs_status = checksum_value(ctext), nil, 2
        if cfg.validate then cs_calc, cs_status = (sh.fixed + sum) % 256, 1 end
        local kind = tail and "delta" or "full"
        if not vis then
            tree_compact_frame(TI.add(tree, sl, tvb(0, n)), 1, n, fl, s, dstb, srcb, kind, list, d, num, visited,
                rec, 0, nm, cs_val, cs_calc, cs_status)
            return true
        end
        -- a shown tree (-V, the GUI's details; speed trick, measured: -V 5 %, a compressed
        -- stream's 8 %): the fields' places, then as dissect_frame (its frame is s[1..fl])
        P.cpos = fl - 1 - #ctext
        fast_positions(sh.ntext, nvals, true)
        tree_full(tree, tvb, s, s, 1, n, fl, true, fl - 1, nil, num, kind, dstb, srcb, list, d, rec, 0, nm,
            cs_val, cs_calc, cs_status)
    end
    return true
end

return { express = express, enabled = EXPRESS }
