-- SharedLink dissector module: parse, one frame's fields and variables into F, the frame record
-- (its arrays and facts): the layout cache in front of the field-by-field parser; the checksum
-- verdict (the one rule) and the kind the fields tell.
-- Loaded by sharedlink.lua (load_module); Wireshark also runs every .lua file of a plugin folder's
-- subfolders as a plugin of its own: this file then does nothing.

local token, M = ...
if type(token) ~= "table" or token.sharedlink_module ~= true then return end

local U, cfg, wsapi = M.util, M.prefs, M.wsapi
local s_byte, s_find, s_match, s_gsub, s_rep = string.byte, string.find, string.match, string.gsub, string.rep
local tonumber, floor, t_concat = tonumber, math.floor, table.concat
local ARROW, CTRL, LETTER, B_PIPE, B_A, B_P = U.ARROW, U.CTRL, U.LETTER, U.B_PIPE, U.B_A, U.B_P
local L_N, L_T, L_Q, L_R, L_D, L_C, L_L, L_E, L_M, L_P, L_G = U.L_N, U.L_T, U.L_Q, U.L_R, U.L_D, U.L_C, U.L_L,
    U.L_E, U.L_M, U.L_P, U.L_G
local valid_type, byte_sum, str_sum, checksum_value = U.valid_type, U.byte_sum, U.str_sum, U.checksum_value
local INFO_MAX, UHEXV, SUM_OF = U.INFO_MAX, U.UHEXV, U.SUM_OF
local to_ordinal, pat_escape = U.to_ordinal, U.pat_escape
local HUGE_INDEX = 4294967295   -- the largest index the uint32 sharedlink.var.index holds

------------------------------------------------------------------------------
-- F, the frame record: one table describing the frame being decoded, filled in order by parse
-- (its fields, variables and the facts they tell), the entry (its place in the packet and the
-- kind its fields tell) and the state writer (its state's answers), and read by state, info and
-- tree (tree_frame, has_experts and info_frame take it as their argument).  Reused for every
-- frame (no per-frame table churn); its arrays are also each module's upvalues (speed trick,
-- measured: a table field is a hash lookup).  Nothing keeps it past the frame.
-- Parse (parse_reset clears the facts; a layout's frame: fill_layout):
--   fields: FL letter byte (false = empty), FS/FE its first and last index in the frame; nf;
--   FV/FC (tree: the variable starting at field i / a field a variable covers);
--   variables: VT type text, VN name (false: positional), VV value (false: no D), VI index, VR is
--   a reply; VTf/VQf/VDf the field numbers of T, Q/R, D (0: none); nv;
--   n_ord/l_ord the N/L ordinals (n_text: N's text; huge_ord: past 9 digits; n_nan: no number);
--   has_e..has_r an E, M, P, G or R field; nq/nd Q and D fields; n_pos positional D fields,
--   n_empty_d empty ones; cmd_start the first E/M field; ord_text N? or L? (a list request);
--   layout: the cached layout that parsed the frame (else false), named: the same when it is a
--   named one (else nil), filled: the layout whose facts F holds; vlen: a layout's values'
--   length; odd: a field whose tree item carries an expert info (an empty field, an unknown
--   letter, an ordinal or type that is not a number); limit: why the frame is past a limit its
--   fields alone tell (a "Limit exceeded: ..." text), else false;
--   the checksum (checksum_verdict): cpos/ctext the C field's start and text, cs_val its value,
--   cs_calc the calculated one, cs_plain two upper-case hex digits (nil: no C field).
-- The entry (dissect_frame; a layout's frame: fill_layout): fkind the kind the fields tell (nil:
--   a data frame), is_data, addrs_ok (both addresses nodes A-P), dstb/srcb (the address bytes,
--   before the state: health reads them); for info and tree: f, fl, a, e,
--   s, terminated, bodyend, malformed (why it is malformed, else nil), num, visited,
--   crlf (CR LF after its ']'), calm (a layout's frame with no possible expert: tree's
--   frame_experts skips it); and the state's answers kind, rec, list, d, miss_n, ne, nm.
------------------------------------------------------------------------------
local FL, FS, FE, FV, FC = {}, {}, {}, {}, {}
local VT, VN, VV, VI, VR, VTf, VQf, VDf = {}, {}, {}, {}, {}, {}, {}, {}
local F = { nv = 0, nf = 0, FL = FL, FS = FS, FE = FE, FV = FV, FC = FC, VT = VT, VN = VN, VV = VV, VI = VI,
    VR = VR, VTf = VTf, VQf = VQf, VDf = VDf }

-- The layout cache (per capture, reset by Pm.reset): mru: node pair -> its recent layouts, newest
-- first (up to MAX_LAYOUTS: a compressed stream's deltas cycle through a few subsets of the
-- variables); bylen: frame length -> the take function (sh.take) of the layout that matched last
-- (nbylen entries; its head, checked before its pattern, tells the node pair: speed trick,
-- measured, no string.byte call a frame for the pair's letters).
-- bylen is an upvalue of its own (speed trick, measured: one table lookup a frame less), one
-- table for the capture (emptied in place), which the entry reads too (Pm.bylen: parse_frame).
local LY, bylen = {}, {}
local MAX_LAYOUTS = 8
local Pm = { F = F, LY = LY, bylen = bylen }
local function bylen_clear()
    for k in pairs(bylen) do bylen[k] = nil end
    LY.nbylen = 0
end
function Pm.reset()
    LY.mru = {}
    bylen_clear()
end
Pm.reset()

-- For tests: SHAREDLINK_NO_FAST=1 turns the layout cache off (every frame parsed field by field),
-- SHAREDLINK_FAST_MARK=1 marks the Info of the packets it parsed ("[fast] "; fast_hit: one of the
-- packet's frames).
local FAST = not wsapi.env.no_fast
local MARKS = { fast = wsapi.env.fast_mark, fast_hit = false }
local FAST_MARK = MARKS.fast

local function parse_reset()
    F.nf, F.nv = 0, 0
    F.n_ord, F.l_ord, F.n_text, F.huge_ord, F.n_nan = nil, nil, nil, nil, nil
    F.has_e, F.has_m, F.has_p, F.has_g, F.has_r = false, false, false, false, false
    F.nq, F.nd, F.n_empty_d, F.n_pos = 0, 0, 0, 0
    F.cpos, F.ctext, F.cmd_start, F.ord_text = nil, nil, nil, false
    F.layout, F.named, F.filled = false, nil, nil
    F.odd, F.limit = false, false
end

-- The header: last index of the content, the address bytes (nil when cut short), the index of
-- the first field (nil: none), and why the frame is malformed (nil: it is not).
local function parse_header(f, fl, terminated)
    local malformed_msg = nil
    if not terminated then malformed_msg = "Unterminated frame (no closing ])" end
    local bodyend = terminated and fl - 1 or fl
    local dstb, srcb = s_byte(f, 3), s_byte(f, 4)
    if bodyend < 3 then dstb = nil end
    if bodyend < 4 then srcb = nil end
    local p
    if bodyend < 5 then
        p = nil
        if not malformed_msg and not srcb then malformed_msg = "Frame too short for a header" end
    elseif s_byte(f, 5) == B_PIPE then
        p = 6
    else
        local q = s_find(f, "|", 5, true)
        p = q and q + 1 or nil
        if not malformed_msg then malformed_msg = "Expected | after the addresses" end
    end
    return bodyend, dstb, srcb, p, malformed_msg
end

------------------------------------------------------------------------------
-- The parser: every field from p on, in one pass, recorded with its place; variables gathered as
-- T/Q/R/D come.  The state of the pass (upvalues, reset by general_reset): g_t/g_tf a pending T's
-- text and field, g_q/g_qf a pending Q or R name and field, g_r: it is an R, g_idx the next
-- variable's index, g_lt the text of the frame's last T when it is a type (else false).
------------------------------------------------------------------------------
local g_t, g_tf, g_q, g_qf, g_r, g_idx, g_lt

-- A variable (type text, name, value, is reply; its T, Q/R and D field numbers).  A name with no
-- T of its own (tf 0) takes the frame's last T (BUL-009: "created with the previously defined
-- type"; docs/fields-sharedlink.md, "Values"): VT its text, VTf 0.
local function add_var(t, q, v, r, tf, qf, df)
    if q and tf == 0 then t = g_lt end
    local nv = F.nv + 1
    F.nv = nv
    VT[nv], VN[nv], VV[nv], VI[nv], VR[nv] = t, q, v, g_idx, r
    VTf[nv], VQf[nv], VDf[nv] = tf, qf, df
end

-- A complete T/Q/D triplet at p (t1 |Q t2 |D t3, ending at fe).
local function take_triplet(p, fe, t1, t2, t3)
    local nf = F.nf
    add_var(t1, t2, t3, false, nf + 1, nf + 2, nf + 3)
    g_idx = g_idx + 1
    F.nq, F.nd = F.nq + 1, F.nd + 1
    if valid_type(t1) then g_lt = t1 else g_lt, F.odd = false, true end
    local q1 = p + #t1 + 2
    local d1 = q1 + #t2 + 2
    FL[nf + 1], FS[nf + 1], FE[nf + 1] = L_T, p, q1 - 2
    FL[nf + 2], FS[nf + 2], FE[nf + 2] = L_Q, q1, d1 - 2
    FL[nf + 3], FS[nf + 3], FE[nf + 3] = L_D, d1, fe
    F.nf = nf + 3
    g_t, g_tf = false, 0   -- no T pending (a stale g_tf gave a later Q/D variable this triplet's T field)
end

-- A D field (text t1, field nf): a variable's value, or a command's argument.
local function take_data(t1, nf)
    F.nd = F.nd + 1
    if F.has_e or F.has_m then return end
    add_var(g_t, g_q, t1, g_r, g_tf, g_qf, nf)
    if not g_q then
        F.n_pos = F.n_pos + 1
        if t1 == "" then F.n_empty_d = F.n_empty_d + 1 end
    end
    g_idx = g_idx + 1
    g_t, g_q, g_r, g_tf, g_qf = false, false, false, 0, 0
end

-- A pending Q or R with no D (a declared or queried name) before a new Q, R or T.
local function flush_name()
    add_var(g_t, g_q, false, g_r, g_tf, g_qf, 0)
    g_idx = g_idx + 1
end

-- An N or L field's text as the tree shows it without an expert: a number 0 .. 2^32-1.
local function ordinal_ok(text)
    local n = tonumber(text)
    return n and n >= 0 and n < 4294967296 and n == floor(n)
end

-- An ordinal as the state reads it: decimal digits only (as a T, and as Python's
-- codec.parse_int: +5, 1e3, 0x10 or 5.5 are no number: 0, the field odd, and an N that is no
-- number makes no full set, F.n_nan), else to_ordinal's.
local function state_ordinal(text, c)
    if text == "" or s_find(text, "[^0-9]") then
        F.odd = true
        if c == L_N then F.n_nan = true end
        return 0
    end
    return to_ordinal(text)
end

-- An N or L field: its ordinal sets the next variable's index (the first one of each only).
local function take_ordinal(c, t1)
    if not ordinal_ok(t1) then F.odd = true end
    local huge = #t1 > 9 and not s_find(t1, "[^0-9]")
    if huge then
        F.odd, F.limit = true, "Limit exceeded: " .. (c == L_N and "N" or "L") .. " has more than 9 digits"
    end
    if c == L_N then
        if F.n_ord then return end
        F.n_ord, F.n_text = state_ordinal(t1, c), t1
        g_idx = F.n_ord
    else
        if F.l_ord then return end
        F.l_ord = state_ordinal(t1, c)
        g_idx = F.l_ord
    end
    -- past max_slots whatever to_ordinal keeps (an unset 32-bit field, N4294967295): its slots
    -- are dropped, not stored from 0, and the frame is no full set (F.huge_ord)
    if huge then g_idx, F.huge_ord = HUGE_INDEX, true end
    if not tonumber(t1) then F.ord_text = true end
end

-- One field other than a triplet: letter c at p, its text t1, ending at fe (field number nf).
local function take_field(c, p, fe, t1, bodyend, nf)
    if c == L_D then
        take_data(t1, nf)
    elseif c == L_Q or c == L_R then
        if g_q then flush_name(); g_t, g_tf = false, 0 end
        g_q, g_qf, g_r = t1, nf, c == L_R
        if g_r then F.has_r = true else F.nq = F.nq + 1 end
    elseif c == L_T then
        if g_q then flush_name(); g_q, g_r, g_qf = false, false, 0 end
        g_t, g_tf = t1, nf
        if valid_type(t1) then g_lt = t1 else g_lt, F.odd = false, true end
    elseif c == L_N or c == L_L then
        take_ordinal(c, t1)
    elseif c == L_C and fe == bodyend then
        F.cpos, F.ctext = p, t1
    elseif c == L_E or c == L_M then
        if c == L_E then F.has_e = true else F.has_m = true end
        if not F.cmd_start then F.cmd_start = p end
    elseif c == L_P then F.has_p = true
    elseif c == L_G then F.has_g = true
    else F.odd = true   -- an unknown letter, or C before the last field
    end
end

-- The fields from p to bodyend.
local function parse_fields(f, p, bodyend)
    g_t, g_tf, g_q, g_qf, g_r, g_idx, g_lt = false, 0, false, 0, false, 0, false
    while p and p <= bodyend + 1 do
        local c = s_byte(f, p)
        local _, fe, t1, t2, t3
        if c == L_T and not g_q then _, fe, t1, t2, t3 = s_find(f, "^T([^]|]*)|Q([^]|]*)|D([^]|]*)", p) end
        if fe and fe <= bodyend then
            take_triplet(p, fe, t1, t2, t3)
            p = fe + 2
        else
            _, fe, t1 = s_find(f, "^[^]|]([^]|]*)", p)
            if fe and fe > bodyend then fe = nil end
            local nf = F.nf + 1
            F.nf = nf
            if not fe then   -- an empty field
                FL[nf], FS[nf], FE[nf] = false, p, p - 1
                F.odd = true
                p = p + 1
            else
                FL[nf], FS[nf], FE[nf] = c, p, fe
                take_field(c, p, fe, t1, bodyend, nf)
                p = fe + 2
            end
        end
    end
    if g_q then add_var(g_t, g_q, false, g_r, g_tf, g_qf, 0) end
end

------------------------------------------------------------------------------
-- The layout cache.  A layout is what a plain frame holds besides its values and its checksum
-- text: addresses, N, and per variable T and Q (named), nothing (positional), or no variable at
-- all (bare: [:AB|N0|Cxx]).  It is learnt from a frame the parser took whose fields carry no
-- expert info; a later frame of the node pair with that layout is matched by one anchored
-- pattern, and its captures go into F as the parser would have put them (the fields' places only
-- for a shown tree: fast_positions).  A cache: whatever it holds, F is what the parser gives.
-- Speed tricks (measured, summary pass): the layout's head up to its first value is found as
-- plain text and the rest matched from there (a pattern matches text one character at a time);
-- the layout that matched a frame of the same length is tried first (a compressed stream
-- interleaves layouts of one prefix, and a pattern that fails late costs most of a match); the
-- checksum is the layout's fixed sum plus one sum over the values joined (TAKE).
------------------------------------------------------------------------------
-- The value classes, written as ranges: a value is any byte but '|', '[', ']', the control
-- characters and DEL (no '[': a frame the cache matched then holds no "[:" but its first, the
-- frame the payload scan finds, see parse_frame's payload; a value with '[' goes to the parser).  Speed
-- trick (measured): the matcher tries a class's items in order and a digit is in the first range,
-- where the negated forms ([^|%]\0-\31\127]) tried every item, escapes costing most (-1.6 and
-- -2.0 thousand instructions a frame, summary pass).  A double-typed value: a plain decimal
-- number only, which tonumber always takes (the tree needs no check for var.badvalue; other
-- doubles, "1e5", " 2" or "+2", go to the parser); its digits as the range [0-9], where %d cost two
-- calls into the C library (tolower, isdigit) a character, and its sign as "%-?", where "[-+]?"
-- cost a class a value (-130 instructions and 6 mispredicted branches a frame in lua5.2).
local VALUE = "([ -Z\\^-{}-~\128-\255]*)"
local DOUBLE = "(%-?[0-9]+%.?[0-9]*)"
local CHECKSUM = "|C([^]|[]*)%](\r?\n?)"

-- A layout's frame, matched and taken into F (the frame record).  The only code made per layout is
-- its matcher (sh.match, made on its first use: layout_matcher): the head found as plain text,
-- the anchored pattern from there, the captures into VV; it returns the checksum text, the line
-- end and the values joined.  Everything else is the ordinary code below (layout_frame): the
-- layout's facts into F (fill_layout), the checksum verdict (checksum_verdict, the one rule), the
-- full verdict.  Speed tricks (measured): the head, pattern and captures are constants and
-- locals of the matcher (no table read, no call passes the captures on); the values are summed
-- as one string, one SUM_OF call instead of one a value (-2.3 thousand instructions a frame,
-- summary pass), a string padded past Lua's 40 bytes for interned strings (sh.npad bytes of "\0"
-- after the values of the frame that taught the layout, LONG in all): Lua makes it without
-- hashing it into its string table, which a short string new each frame fills (-1.7 thousand
-- instructions a frame, time -2.7 %, summary pass).  The pattern takes the line end after the
-- ']' (CR LF, CR, LF or "", as the entry's line_end: no string.byte call).
local parse_frame   -- (below)
local LONG = 44   -- (a layout's values joined and padded: longer than 40 bytes, give or take 3)

-- The one checksum rule (docs/fields-sharedlink.md, "Bad checksums"; BUL-009): the sum of the
-- bytes from ':' through the 'C' of the checksum field, modulo 256, against the field's text
-- read as hex.  Returns the status (1 good, 0 bad, 2 unverified: validate_checksum off), whether
-- the text is two upper-case hex digits (plain: the form without sharedlink.checksum.format),
-- its value (nil: not 1 to 8 hex digits) and the calculated one (nil: not validated).  sum: the
-- bytes' sum, not reduced (ignored when not validated), which the frame record keeps (F.cs_sum;
-- checksum_facts gives the rest to info and tree).
local function checksum_verdict(ctext, sum)
    local plain = UHEXV[ctext]
    local cs_val = plain or checksum_value(ctext)
    if not cfg.validate then return 2, plain ~= nil, cs_val, nil end
    local cs_calc = sum % 256
    return cs_val == cs_calc and 1 or 0, plain ~= nil, cs_val, cs_calc
end

-- The checksum's facts into F (cs_plain, cs_val, cs_calc; nil with no C field), for info and the
-- tree: the frames that need them (the entry).
function Pm.checksum_facts()
    if not F.cpos then F.cs_plain, F.cs_val, F.cs_calc = nil, nil, nil; return end
    local _, plain, cs_val, cs_calc = checksum_verdict(F.ctext, F.cs_sum)
    F.cs_plain, F.cs_val, F.cs_calc = plain, cs_val, cs_calc
end

-- A layout's matcher, made on its first use: a chunk of several lines named after its layout
-- (an error reads "layout [:AB|N0|T2|QLat|D...:5:"), its environment one table (E: the names the
-- code reads, taken into locals once).
local function layout_matcher(sh)
    local n, vs, lines = sh.n, {}, {}
    for k = 1, n do vs[k] = "v" .. k end
    local caps = n > 0 and (t_concat(vs, ", ") .. ", ") or ""
    lines[1] = "local VV, s_find, s_match, HEAD, PAT, AT, PAD = VV, s_find, s_match, HEAD, PAT, AT, PAD"
    lines[2] = "return function(f)"
    lines[3] = "    if s_find(f, HEAD, 1, true) ~= 1 then return nil end"
    lines[4] = "    local " .. caps .. "ctext, le = s_match(f, PAT, AT)"
    lines[5] = "    if not ctext then return nil end"
    for k = 1, n do lines[5 + k] = "    VV[" .. k .. "] = v" .. k end
    local joined = n > 0 and (t_concat(vs, " .. ") .. (sh.pad and " .. PAD" or "")) or '""'
    lines[n + 6] = "    return ctext, le, " .. joined
    lines[n + 7] = "end"
    local E = { VV = VV, s_find = s_find, s_match = s_match, HEAD = sh.head, PAT = sh.pat, AT = sh.at, PAD = sh.pad }
    local name = "=layout " .. sh.head .. (n > 0 and (sh.named and "|..." or "|D...") or "")
    sh.match = assert(load(t_concat(lines, "\n"), name, "t", E))()
    return sh.match
end

-- A positional layout's frame: its empty D fields (F.n_empty_d; full without state needs none).
local function positional_empty(n)
    local n_empty_d = 0
    for k = 1, n do if VV[k] == "" then n_empty_d = n_empty_d + 1 end end
    F.n_empty_d = n_empty_d
    return n_empty_d == 0
end

-- The fields' places in a frame the layout cache parsed (N, T/Q/D triplets or D fields, C), for
-- a shown tree: the layout fixes every field but the values, whose lengths place the rest.
local function fast_positions(sh)
    local ntext, n, named = sh.ntext, sh.n, sh.named
    FL[1], FS[1], FE[1] = L_N, 6, 6 + #ntext
    local p, i = 8 + #ntext, 1
    for k = 1, n do
        if named then
            local t, q = VT[k], VN[k]
            FL[i + 1], FS[i + 1], FE[i + 1] = L_T, p, p + #t
            p = p + #t + 2
            FL[i + 2], FS[i + 2], FE[i + 2] = L_Q, p, p + #q
            p = p + #q + 2
            VTf[k], VQf[k] = i + 1, i + 2
            i = i + 2
        else
            VTf[k], VQf[k] = 0, 0
        end
        local v = VV[k]
        FL[i + 1], FS[i + 1], FE[i + 1] = L_D, p, p + #v
        VDf[k] = i + 1
        p = p + #v + 2
        i = i + 1
    end
    FL[i + 1], FS[i + 1], FE[i + 1] = L_C, p, p + #F.ctext
    F.nf = i + 1
end

-- A layout's names, types, indexes and facts into F, as the parser leaves them for such a frame
-- (parse_reset, then what a data frame of N, variables and C has); they stay while the next frames
-- have the layout (F.filled, cleared by parse_reset; speed trick, measured).  After another
-- layout's frame (F.layout) only what differs between layouts is written (speed trick, measured:
-- a compressed stream changes layout every frame).
local function fill_layout(sh)
    if not F.layout then
        parse_reset()
        F.fkind, F.is_data, F.addrs_ok = nil, true, true   -- (a data frame between nodes A-P)
    end
    F.dstb, F.srcb = sh.dstb, sh.srcb
    local n, st, sn, ord = sh.n, sh.T, sh.N, sh.ord
    for k = 1, n do VT[k], VN[k], VI[k], VR[k] = st[k], sn[k], ord + k - 1, false end
    F.nv, F.nd, F.n_ord, F.n_text, F.layout, F.filled = n, n, ord, sh.ntext, sh, sh
    if sh.named then
        F.nq, F.n_pos, F.n_empty_d, F.named = n, 0, 0, sh
    else
        F.nq, F.n_pos, F.named = 0, n, nil
    end
end

-- The function that takes a frame of layout sh (sh.take, made when the layout is learnt; the
-- layout's fields its upvalues: speed trick, measured, no table read for them), called as
-- parse_frame is (try: nil when f does not have the layout, else parse_frame's answer, a tail
-- call).  Returns what parse_frame returns.
local function layout_frame(sh)
    local npad, flen1, full0, named, fixed, n = sh.npad, sh.flen1, sh.full0, sh.named, sh.fixed, sh.n
    local quiet, dstb, srcb = sh.quiet, sh.dstb, sh.srcb
    local match
    match = function(f1) match = layout_matcher(sh); return match(f1) end   -- (made on its first use)
    return function(f, fl, terminated, vis, payload, try)
        local ctext, le, all = match(f)
        if not ctext then
            if try then return nil end
            return parse_frame(f, fl, terminated, vis, payload)
        end
        if F.filled ~= sh then fill_layout(sh) end
        local vlen = #all - npad
        local cpos = flen1 + vlen
        F.ctext, F.cpos, F.vlen = ctext, cpos, vlen
        if FAST_MARK then MARKS.fast_hit = true end
        local full = full0
        if not named then full = positional_empty(n) and full end
        if vis then fast_positions(sh) end
        local sum = fixed
        if vlen > 40 then sum = sum + byte_sum(all, 1, vlen)
        elseif vlen > 0 then sum = sum + SUM_OF[vlen](s_byte(all, 1, vlen)) end
        F.cs_sum = sum
        local cs_status, plain = checksum_verdict(ctext, sum)
        -- (quiet, a layout with no possible expert: a good upper-case checksum adds none)
        return cpos + #ctext, dstb, srcb, nil, cs_status, quiet and cs_status == 1 and plain, full, le
    end
end
------------------------------------------------------------------------------
-- Learning a layout (from a frame the parser took).
------------------------------------------------------------------------------
-- Whether every variable of the parsed frame is a T/Q/D triplet with a valid type (named), or a
-- D alone (positional).
local function all_named()
    for k = 1, F.nv do
        if not (VT[k] and VN[k] and VV[k] and valid_type(VT[k])) or VR[k] then return false end
    end
    return true
end
local function all_positional()
    for k = 1, F.nv do
        if VT[k] or VN[k] or not VV[k] then return false end
    end
    return true
end

-- Which layout the parsed frame has: "named" (N, T/Q/D triplets, C), "positional" (N, D fields,
-- C), "bare" (N0, C), or nil (none the cache keeps: at most 8 variables).
local function layout_kind(f)
    local nv, nf = F.nv, F.nf
    if not (F.n_text and F.cpos) or F.ord_text or s_byte(f, 6) ~= L_N or nv > 8 then return nil end
    if nv == 0 then return (nf == 2 and F.n_ord == 0) and "bare" or nil end
    if nf == 3 * nv + 2 and F.n_pos == 0 and all_named() then return "named" end
    if nf == nv + 2 and F.n_pos == nv and F.nq == 0 and not F.has_r and all_positional() then return "positional" end
    return nil
end

-- The Info pieces of a named layout or one of no value (sh; bare: the head alone), what info.lua's
-- layout_piece puts before each value, and the room its values have in INFO_MAX.
local function named_info(sh, dstb, srcb)
    local sn, nv = sh.N, sh.n
    local head = LETTER[srcb] .. ARROW .. LETTER[dstb] .. " full"
    local dhead = LETTER[srcb] .. ARROW .. LETTER[dstb] .. " delta"
    local first = nv > 0 and (" " .. s_gsub(sn[1], CTRL, "?") .. "=") or ""
    local pieces, dpieces, ilen = { head .. first }, { dhead .. first }, #head
    for k = 1, nv do
        if k > 1 then
            pieces[k] = " " .. s_gsub(sn[k], CTRL, "?") .. "="
            dpieces[k] = pieces[k]
        end
        ilen = ilen + #sn[k] + 2
    end
    sh.pieces, sh.dpieces = pieces, dpieces
    sh.info_room, sh.dinfo_room = INFO_MAX - ilen, INFO_MAX - (ilen + #dhead - #head)
end

-- Whether a layout's types hold a long (whose values need parse_long to rule out var.badvalue).
local function has_long(tv)
    for k = 1, 8 do if tv[k] == 0 then return true end end
    return false
end

-- A new layout from the parsed frame f of kind (layout_kind): its head, pattern and sums.
local function new_layout(f, kind, dstb, srcb)
    local nv = F.nv
    local named = kind == "named"
    local head = "[:" .. LETTER[dstb] .. LETTER[srcb] .. "|N" .. F.n_text
    local st, sn, tv, parts = {}, {}, {}, {}
    local fixed = byte_sum(f, 2, F.cpos)
    for k = 1, nv do
        local tq = ""
        if named then
            st[k], sn[k], tv[k] = VT[k], VN[k], valid_type(VT[k])
            tq = "|T" .. VT[k] .. "|Q" .. VN[k]
        end
        if k == 1 then head = head .. tq .. "|D" else parts[k] = pat_escape(tq .. "|D") end
        parts[k] = (parts[k] or "") .. (tv[k] == 2 and DOUBLE or VALUE)
        fixed = fixed - str_sum(VV[k])
    end
    parts[nv + 1] = CHECKSUM
    local vlen = 0
    for k = 1, nv do vlen = vlen + #VV[k] end
    local sh = { head = head, at = #head + 1, pat = "^" .. t_concat(parts), n = nv, named = named, T = st, N = sn,
        TV = named and tv or nil, has_long = named and has_long(tv), ord = F.n_ord, ntext = F.n_text,
        fixed = fixed % 256, flen1 = F.cpos - vlen, dstb = dstb, srcb = srcb,
        npad = nv > 0 and math.max(0, LONG - vlen) or 0 }
    if sh.npad > 0 then sh.pad = s_rep("\0", sh.npad) end
    -- quiet: no value of the layout can carry an expert info (var.badvalue; see tree's has_experts):
    -- a named layout with no long, or one of no value at all (bare: a compressed stream's deltas)
    sh.quiet = (named and not sh.has_long) or nv == 0
    sh.full0 = nv > 0 and F.n_ord == 0   -- full without state, but for empty positional D fields
    sh.key = sh.head .. "\0" .. sh.pat
    if named or nv == 0 then named_info(sh, dstb, srcb) end
    sh.take = layout_frame(sh)   -- (last: it keeps the layout's fields)
    return sh
end

-- Remember the parsed frame's layout for the node pair (key); a layout known already comes first
-- again, the same table (the direction's names_is is the layout itself).
local function learn_layout(f, key, dstb, srcb)
    local kind = layout_kind(f)
    if not kind then return end
    local sh = new_layout(f, kind, dstb, srcb)
    local mru = LY.mru[key]
    if not mru then mru = {}; LY.mru[key] = mru end
    for k = 1, #mru do
        if mru[k].key == sh.key then
            if k > 1 then table.insert(mru, 1, table.remove(mru, k)) end
            return
        end
    end
    if #mru >= MAX_LAYOUTS then mru[#mru] = nil end
    table.insert(mru, 1, sh)
end

------------------------------------------------------------------------------
-- A frame: the layout cache, else the header and the parser (which teaches the cache).
------------------------------------------------------------------------------
-- Checksum verdict of a frame the parser took, before the state (a frame with a bad checksum
-- changes no state): checksum_verdict's, nil with no C field.
local function parsed_checksum(f)
    local cpos = F.cpos
    if not cpos then return nil end
    local sum = cfg.validate and byte_sum(f, 2, cpos) or 0
    F.cs_sum = sum
    return (checksum_verdict(F.ctext, sum))
end

-- A frame the layout cache does not have: the header, then the fields (parse_frame's answers).
local function parse_fields_of(f, fl, terminated)
    parse_reset()
    local bodyend, dstb, srcb, p, malformed_msg = parse_header(f, fl, terminated)
    if p then parse_fields(f, p, bodyend) end
    -- positional slots and declared entries at or past max_slots (their state is dropped); a
    -- named value (a name and its D) is no slot, whatever its index (indexes only grow: the loop
    -- walks the variables past max_slots only)
    local max_slots = cfg.LIM.max_slots
    if F.nv > 0 and VI[F.nv] >= max_slots and not F.limit then
        local decl = F.n_ord or F.l_ord
        for v = F.nv, 1, -1 do
            if VI[v] < max_slots then break end
            if not VN[v] or (decl and not VV[v]) then
                F.odd, F.limit = true, "Limit exceeded: a slot or ordinal at or past " .. max_slots .. " (max_slots)"
                break
            end
        end
    end
    -- a node pair's frame whose fields carry no expert info teaches the cache its layout
    if p == 6 and not malformed_msg and not F.odd and dstb >= B_A and dstb <= B_P and srcb >= B_A and srcb <= B_P then
        learn_layout(f, dstb * 256 + srcb, dstb, srcb)
    end
    return bodyend, dstb, srcb, malformed_msg, parsed_checksum(f)
end

-- Parse a frame.  Returns the last index of the content, the address bytes, why it is malformed
-- (nil: it is not), the checksum status (checksum_verdict; the rest in F) and, for a layout's frame, whether
-- it can have no expert info (quiet: see the entry), is full without state (else nil) and the
-- line end after its ']' (the layout's pattern takes it).
-- vis: a shown tree (it needs the fields' places).  payload: f is the whole payload and fl its
-- length, and only the layout cache is tried, for the frame the payload starts with (nil when
-- it has none; a layout's head starts with "[:" and the addresses, so the frame needs no header
-- check).
--
-- The layout cache: the layout that matched the same length last is tried first (fl: the index of
-- the frame's ']', or the payload's length; its matcher checks the head; the entry calls its
-- take function, sh.take, for it), then the node pair's recent ones.  A frame it has goes into F:
-- its values (VV), its variables and the facts a layout's frame has (a data frame: N, then
-- T/Q/D triplets or D fields, then C; the facts only other kinds have, has_e..has_r, l_ord,
-- cmd_start, ord_text, are read for those alone), and its checksum verdict is the layout's fixed
-- sum plus the values'.  Speed tricks
-- (measured): the layout's names, types, indexes and facts stay in F while the next frames have
-- its layout (F.filled, cleared by the parser): such a frame writes its values and its
-- checksum's facts.
-- The entry calls the layout's take function itself when bylen has one for fl (speed trick,
-- measured: one call a frame less); parse_frame is the rest: the node pair's recent layouts,
-- newest first (the one that matches comes first and is remembered for fl), else the parser.
function parse_frame(f, fl, terminated, vis, payload)
    local mru = false
    if FAST and terminated and fl >= 6 then
        local dstb, srcb = s_byte(f, 3, 4)
        mru = LY.mru[dstb * 256 + srcb]
    end
    if mru then
        for k = 1, #mru do
            local sh = mru[k]
            local bodyend, dstb, srcb, m, cs_status, quiet, full, le =
                sh.take(f, fl, terminated, vis, payload, true)
            if bodyend then
                if k > 1 then table.remove(mru, k); table.insert(mru, 1, sh) end
                if LY.nbylen >= 4096 then bylen_clear() end
                bylen[fl], LY.nbylen = sh.take, LY.nbylen + 1
                return bodyend, dstb, srcb, m, cs_status, quiet, full, le
            end
        end
    end
    if payload then return nil end
    return parse_fields_of(f, fl, terminated)
end

-- The kind the fields alone tell; a data frame (full or delta, told by the state) gives nil, true.
local function kind_of_fields(malformed_msg)
    if F.layout then return nil, true end   -- a layout's frame is a data frame
    if malformed_msg then return "malformed", false end
    if F.has_e or F.has_m then return "command", false end
    if F.has_p then return "ping", false end
    if F.has_g then return "pong", false end
    if F.has_r then return "reply", false end
    local nd, nq, ord_text = F.nd, F.nq, F.ord_text
    if nd == 0 and nq > 0 and (F.l_ord or F.n_ord) and not ord_text then return "declaration", false end
    if nd == 0 and (nq > 0 or ord_text) then return "query", false end
    if nd > 0 or F.n_ord then return nil, true end
    return "other", false
end

Pm.parse_frame, Pm.kind_of_fields, Pm.MARKS = parse_frame, kind_of_fields, MARKS
return Pm
