-- SharedLink dissector module: records, what the first pass leaves for later passes about a frame
-- (get_rec), carried-only records packed as text lines (carried_store).  Loaded by sharedlink.lua
-- (load_module); Wireshark also runs every .lua file of a plugin folder's subfolders as a plugin of
-- its own: this file then does nothing.

local token = ...
if type(token) ~= "table" or token.sharedlink_module ~= true then return end

local s_find, s_sub = string.find, string.sub
local tostring, tonumber = tostring, tonumber
local floor = math.floor
local t_concat = table.concat

local R = {}
local recs          -- frame number -> { [subkey] = record }
local cr_pend, cr_npieces, cr_store, cr_first  -- packed carried records
local sk_str, sk_str_n       -- frame key -> its text, for them

-- per-capture state (init)
function R.reset()
    recs = {}
    cr_pend, cr_npieces, cr_first = {}, 0, {}
    cr_store = { bytes = nil, size = 0, off = {}, len = {}, last = 0, last_text = nil }
    sk_str, sk_str_n = {}, 0
end
R.reset()

-- Per-frame record, kept only for frames that need one.  recs[num] is the record
-- itself (rec.sk identifies the frame within the packet) or, when several frames of
-- one packet have records, a table sk -> record.  A record's array part holds the
-- carried values of its empty D fields: value, frame, value, frame, ...
local CARRY = {}
R.CARRY = CARRY   -- carried values of the current frame: value, frame, value, frame, ...
local MISS = {}
R.MISS = MISS    -- named variables missing from the current frame: name, value, frame, ...
local CPARTS = {}

-- Carried-only records (the bulk of a compressed stream) are kept as text lines
-- "num|sk|value|frame|value|frame..." (a D value never holds "|" or a line break;
-- "" = none; a carried named value is stored as "=" .. value, as it may be ""),
-- packed into chunks (carried_flush): Wireshark runs full Lua garbage collections
-- during a capture, and their cost grows with the number of live Lua objects.
-- FROM_STR: frame number -> its text (the carried values' frames), up to FROM_STR_MAX, then emptied:
-- a compressed stream's carried values come from a few recent frames, and 4096 texts kept held up
-- to 280 KB of live heap, which the collector walks (docs/perf-log.md, 7 December 2026)
local FROM_STR, from_str_n, FROM_STR_MAX = {}, 0, 256
local function from_text(fr)
    if not fr then return "" end
    local t = FROM_STR[fr]
    if not t then
        if from_str_n >= FROM_STR_MAX then FROM_STR, from_str_n = {}, 0 end
        t = tostring(fr)
        FROM_STR[fr] = t
        from_str_n = from_str_n + 1
    end
    return t
end

-- The text of a frame key (sk), kept for the few a capture has.
local function sk_text(sk)
    local sks = sk_str[sk]
    if not sks then
        sks = tostring(sk)
        if sk_str_n < 4096 then sk_str[sk] = sks; sk_str_n = sk_str_n + 1 end
    end
    return sks
end

-- Record lines wait in cr_pend as pieces (cr_npieces), each line's first piece its frame number
-- (a number: cr_pend[1] is the first pending line's) and its last "\n", and are packed into a
-- chunk "\n" .. lines once CHUNK_PIECES pieces wait (256 lines of a compressed stream's deltas,
-- two pieces each: subset_line).  Speed trick (measured, compressed
-- capture): the chunks are kept in one ByteArray (cr_store), outside the Lua heap, as the
-- collector's pace follows the heap's live size: kept as Lua strings, they made every
-- collection rarer and each one sweep more garbage, a cost to every allocation of the pass
-- (-2.6 us a frame).  cr_store.off/len: chunk i's place in it; last/last_text: the chunk read last.
local CHUNK_PIECES = 512
local function carried_flush()
    if cr_npieces == 0 then return end
    local text = "\n" .. t_concat(cr_pend, "", 1, cr_npieces)
    local st = cr_store
    if not st.bytes then st.bytes = ByteArray.new() end
    st.bytes:append(ByteArray.new(text, true))
    local i = #st.off + 1
    st.off[i], st.len[i], st.size = st.size, #text, st.size + #text
    cr_first[i] = cr_pend[1]   -- (the frame number of its first line)
    cr_npieces = 0
end

-- The text of chunk i.
local function carried_chunk(i)
    local st = cr_store
    if st.last ~= i then st.last, st.last_text = i, st.bytes:raw(st.off[i], st.len[i]) end
    return st.last_text
end

-- A record line has been put in cr_pend after the pieces already there, ending with its "\n" at
-- index i (carried_store).
local function carried_line_end(i)
    cr_npieces = i
    if i >= CHUNK_PIECES then carried_flush() end
end

-- The named part of a line: name|value|frame|... for the nm/3 triples in MISS.
local function carried_names_text(nm, n)
    for k = 1, nm, 3 do
        -- a named value can be "" (an empty D, rule 3): present values are stored as
        -- "=" .. value so that "" still means none
        local v = MISS[k + 1]
        CPARTS[n + 1], CPARTS[n + 2], CPARTS[n + 3] = MISS[k], v and ("=" .. v) or "", from_text(MISS[k + 2])
        n = n + 3
    end
    return n
end

-- A carried named value's piece of a line, "|name|=value|frame" (false: it holds a line break),
-- made and kept per name (PIECE, PV, PF; up to 4096 names): carried_store uses it while the
-- name's value and frame stay the same.
-- Speed trick (measured, compressed capture): a delta's line goes in as these pieces, no string
-- made for it until its chunk.
local function piece_text(name, v, fr)
    return "|" .. name .. (v and ("|=" .. v) or "|") .. "|" .. from_text(fr)
end
local PIECE, PV, PF, piece_n = {}, {}, {}, 0
local function name_piece(name, v, fr)
    local t = piece_text(name, v, fr)
    if s_find(t, "\n", 1, true) then t = false end
    if piece_n >= 4096 then PIECE, PV, PF, piece_n = {}, {}, {}, 0 end
    if PIECE[name] == nil then piece_n = piece_n + 1 end
    PIECE[name], PV[name], PF[name] = t, v, fr
    return t
end

-- A line's text after its frame number when it carries named values alone: "|sk|kind|0", per key.
local HEAD, head_n = {}, 0
local function named_head(sk, kind)
    local k = kind == "f" and -sk or sk
    local t = HEAD[k]
    if not t then
        t = "|" .. sk_text(sk) .. "|" .. kind .. "|0"
        if head_n >= 4096 then HEAD, head_n = {}, 0 end
        HEAD[k], head_n = t, head_n + 1
    end
    return t
end

-- The line of a delta that carries named values alone: a known subset's (sub, the state writer's:
-- sub.names the names it carries, their values and frames in vals and from, a direction's), as
-- carried_store makes it from MISS.  Speed trick (measured, compressed capture): the line after its
-- frame number is made once and kept in sub (sub.line, for the frame key sub.lsk; sub.run: its
-- names' part) while none of those values changes (the state writer clears both when another
-- layout's values were stored in the direction since: state.lua state_data), so a delta of the
-- same layout as the last one puts in two pieces, its number and that text.  Returns false when a
-- value holds a line break (then the caller makes a table record).
local function subset_text(sk, sub, d)
    local run = sub.run
    if not run then
        run = ""
        local names, vals, from = sub.names, d.vals, d.from
        for k = 1, #names do
            local name = names[k]
            run = run .. piece_text(name, vals[name], from[name])
        end
        if s_find(run, "\n", 1, true) then return false end
        sub.run = run
    end
    local line = (HEAD[sk] or named_head(sk, "d")) .. run .. "\n"   -- (a delta's head: key sk)
    sub.line, sub.lsk = line, sk
    return line
end

local function subset_line(num, sk, sub, d)
    local line = sub.line
    if not line or sub.lsk ~= sk then
        line = subset_text(sk, sub, d)
        if not line then return false end
    end
    local i = cr_npieces + 2
    cr_pend[i - 1], cr_pend[i] = num, line
    -- (carried_line_end, written out: one call a delta less)
    cr_npieces = i
    if i >= CHUNK_PIECES then carried_flush() end
    return true
end

-- Line: num|sk|kind|ne|value|frame|...(ne/2 pairs)|name|value|frame|...(nm/3 triples).  Returns
-- false when a value holds a line break (then the caller makes a table record).
local function carried_store(num, sk, ne, nm, kind)
    local i = cr_npieces
    if ne == 0 then
        -- named values alone: the line as pieces (name_piece)
        local pend = cr_pend
        pend[i + 1], pend[i + 2] = num, named_head(sk, kind)
        i = i + 2
        for k = 1, nm, 3 do
            local name, v, fr = MISS[k], MISS[k + 1], MISS[k + 2]
            local t = PIECE[name]
            if t == nil or PV[name] ~= v or PF[name] ~= fr then t = name_piece(name, v, fr) end
            if not t then return false end
            i = i + 1
            pend[i] = t
        end
        pend[i + 1] = "\n"
        carried_line_end(i + 1)
        return true
    end
    CPARTS[1], CPARTS[2], CPARTS[3], CPARTS[4] = "", sk_text(sk), kind, ne   -- (the line after its number)
    local n = 4
    for k = 1, ne, 2 do
        CPARTS[n + 1], CPARTS[n + 2] = CARRY[k] or "", from_text(CARRY[k + 1])
        n = n + 2
    end
    n = carried_names_text(nm, n)
    local line = t_concat(CPARTS, "|", 1, n)
    if s_find(line, "\n", 1, true) then return false end   -- a line break in a value: a table record
    cr_pend[i + 1], cr_pend[i + 2], cr_pend[i + 3] = num, line, "\n"
    carried_line_end(i + 3)
    return true
end

local function carried_parse(line)
    local rec = {}
    local parts, n = CPARTS, 0
    local p = 1
    while true do
        local q = s_find(line, "|", p, true)
        n = n + 1
        parts[n] = s_sub(line, p, (q or 0) - 1)
        if not q then break end
        p = q + 1
    end
    rec.sk = tonumber(parts[2])
    rec.kind = parts[3]
    local ne = tonumber(parts[4]) or 0
    for k = 1, ne, 2 do
        local v = parts[k + 4]
        rec[k] = v ~= "" and v or false
        rec[k + 1] = tonumber(parts[k + 5]) or false
    end
    local i = ne + 5
    if i + 2 <= n then
        local miss = {}
        while i + 2 <= n do
            local v = parts[i + 1]
            miss[#miss + 1] = parts[i]
            miss[#miss + 1] = v ~= "" and s_sub(v, 2) or false
            miss[#miss + 1] = tonumber(parts[i + 2]) or false
            i = i + 3
        end
        rec.miss = miss
    end
    return rec
end

local function carried_lookup(num, sk)
    if cr_npieces > 0 and num >= cr_pend[1] then carried_flush() end
    -- last chunk whose first frame is <= num
    local lo, hi = 1, #cr_first
    local found = nil
    while lo <= hi do
        local mid = floor((lo + hi) / 2)
        if cr_first[mid] <= num then found = mid; lo = mid + 1 else hi = mid - 1 end
    end
    if not found then return nil end
    -- the packet's lines may begin in the chunks before, when its first line in this one
    local key = "\n" .. num .. "|" .. sk .. "|"
    local chunk = carried_chunk(found)
    local a = s_find(chunk, key, 1, true)
    while not a and found > 1 and cr_first[found] == num do
        found = found - 1
        chunk = carried_chunk(found)
        a = s_find(chunk, key, 1, true)
    end
    if not a then return nil end
    local b = s_find(chunk, "\n", a + 1, true)
    return carried_parse(s_sub(chunk, a + 1, b - 1))
end

local function get_rec(num, sk, create)
    local r = recs[num]
    if r == nil then
        if not create then
            if cr_npieces == 0 and cr_first[1] == nil then return nil end   -- no carried-only records at all
            return carried_lookup(num, sk)
        end
        r = { sk = sk }
        recs[num] = r
        return r
    end
    if r.sk == sk then return r end
    if r.sk ~= nil then
        if not create then return carried_lookup(num, sk) end
        r = { [r.sk] = r }
        recs[num] = r
    end
    local rec = r[sk]
    if not rec then
        if not create then return carried_lookup(num, sk) end
        rec = { sk = sk }
        r[sk] = rec
    end
    return rec
end

R.carried_store, R.subset_line, R.get_rec = carried_store, subset_line, get_rec

return R
