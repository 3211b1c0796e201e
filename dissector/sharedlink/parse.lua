-- SharedLink dissector module: parse, one frame's fields and variables into the arrays of P (the layout cache in
-- front of the field-by-field parser), its checksum verdict and the kind its fields tell.
-- Loaded by sharedlink.lua (load_module); Wireshark also runs every .lua file of a plugin folder's
-- subfolders as a plugin of its own: this file then does nothing.

local token, M = ...
if type(token) ~= "table" or token.sharedlink_module ~= true then return end

local U, cfg, wsapi, s_byte = M.util, M.prefs, M.wsapi, string.byte
local s_find, s_gsub, s_rep, tonumber = string.find, string.gsub, string.rep, tonumber
local floor, t_concat, ARROW, CTRL = math.floor, table.concat, U.ARROW, U.CTRL
local B_PIPE, B_A, B_P, L_N = U.B_PIPE, U.B_A, U.B_P, U.L_N
local L_T, L_Q, L_R, L_D = U.L_T, U.L_Q, U.L_R, U.L_D
local L_C, L_L, L_E, L_M = U.L_C, U.L_L, U.L_E, U.L_M
local L_P, L_G, LETTER, valid_type = U.L_P, U.L_G, U.LETTER, U.valid_type
local byte_sum, str_sum, checksum_value, to_ordinal = U.byte_sum, U.str_sum, U.checksum_value, U.to_ordinal
local pat_escape = U.pat_escape


-- What parsing found in the current frame (P, read by state, info and tree): the fields and
-- variables as arrays (below) and the facts in P's other keys (see parse_reset).
local P = { nv = 0, nf = 0 }
-- the layouts the fast paths and the express lane know (per capture, reset by Pm.reset):
-- named: node pair -> layouts of its recent plain named frames, newest first; pos: node pair ->
-- the layout of its last plain positional frame; bare: node pair -> its last bare frame
-- ([:AB|N0|Cxx]); xlen: node pair * 65536 + payload length -> the layout that matched last
-- (the express lane), xlen_n entries
local LY = {}
local MAX_SHAPES = 8
local Pm = { P = P, LY = LY }
function Pm.reset()
    LY.named, LY.pos, LY.bare, LY.xlen, LY.xlen_n = {}, {}, {}, {}, 0
end
Pm.reset()
-- For the express lane (see express), one per value count n, made the same way:
-- EXPRESS_SUMS[n](v1, ..., vn, ctext) -> the values' total length, the sum of their bytes and
-- ctext.  Speed trick (measured): the values are summed as one string, one str_sum instead of
-- one a value (-2.3 thousand instructions a frame, summary pass; the joined string is short,
-- interned and soon garbage).
local EXPRESS_SUMS = {}
for n = 1, 8 do
    local args = {}
    for k = 1, n do args[k] = "v" .. k end
    EXPRESS_SUMS[n] = assert(load("local str_sum = ... return function(" .. t_concat(args, ", ") ..
        ", ctext) local all = " .. t_concat(args, " .. ") .. " return #all, str_sum(all), ctext end",
        "=EXPRESS_SUMS", "t", {}))(str_sum)
end

-- Frame parsing into reusable arrays (no per-frame table churn)
------------------------------------------------------------------------------
-- fields (only recorded when a tree is built): letter byte (false = empty), start, end in f
local FL, FS, FE = {}, {}, {}
local FV, FC = {}, {}     -- rendering: variable starting at field i / field covered by a variable
-- variables: type text, name, value (false = no D), index, is reply; field numbers of T, Q/R, D
local VT, VN, VV, VI, VR = {}, {}, {}, {}, {}
local VTf, VQf, VDf = {}, {}, {}


-- One frame, in phases: parse (fast paths, else every field), learn the layout for the
-- fast paths, checksum verdict, kind, state (first pass: compute and store; later passes:
-- read the record), Info column, tree (compact when nobody sees it, else full).
------------------------------------------------------------------------------
-- What parsing found in the current frame, beside the field and variable arrays above
-- (pr_*: module-level locals, reset by parse_reset; speed trick, measured: fields of a table
-- cost 3 us a frame more).  n_ord/l_ord: the N/L ordinals (n_text: N's text);
-- has_e..has_r: an E, M, P, G or R field; nq/nd: Q and D fields; n_pos: positional D fields,
-- n_empty_d: empty ones; cpos/ctext: the checksum field's start and text; cmd_start: the
-- first E/M field; ord_text: N? or L? (a list request); fast_sh: the named layout matched,
-- fast_hit: a fast path parsed the frame, fast_sum: the checksum it computed.
-- P.odd: parse_general met a field whose tree item carries an expert info (an empty field, an
-- unknown letter, an ordinal or type that is not a number)
-- P.limit: why the frame is past a limit its fields alone tell (a "Limit exceeded: ..." text),
-- else false

-- For tests, marks on the Info of the packets a speed trick took: SHAREDLINK_EXPRESS_MARK=1 the
-- express lane's ("[express] "), SHAREDLINK_FAST_MARK=1 parse_frame's fast paths' ("[fast] ";
-- fast_hit: one of the packet's frames took one).
local MARKS = { express = wsapi.env.express_mark and "[express] ", fast = wsapi.env.fast_mark, fast_hit = false }

-- parse_frame and the helpers only it uses (a block: the main chunk may hold 200 locals);
-- fast_positions serves the express lane too
local parse_frame, fast_positions
do
    -- SHAREDLINK_NO_FAST=1 turns the fast paths off (tests: every frame parsed field by field)
    local FAST = not wsapi.env.no_fast

    -- The layouts' value classes, written as ranges: a value is any byte but '|', ']', the
    -- control characters and DEL (VALUE, the phases' fast paths) and also not '[' (XVALUE, the
    -- express lane: a "[:" there would make the phases split the frame).  Speed trick
    -- (measured): the matcher tries a class's items in order and a digit is in the first range,
    -- where the negated forms ([^|%]\0-\31\127]) tried every item, escapes costing most
    -- (-1.6 and -2.0 thousand instructions a frame, summary pass); XCHECKSUM ends the payload
    -- after the checksum and at most CR LF.
    local VALUE = "([ -\\^-{}-~\128-\255]*)"
    local XVALUE = "([ -Z\\^-{}-~\128-\255]*)"
    local XCHECKSUM = "|C([^][|]*)%]\r?\n?$"
    -- a double-typed value in the express lane: a plain decimal number only, which tonumber always
    -- takes (speed trick, measured: the lane needs no tonumber to know the value has no
    -- var.badvalue; other doubles, "1e5" or " 2", go to the phases)
    local XDOUBLE = "([-+]?%d+%.?%d*)"
    local function parse_reset()
        P.nf, P.nv = 0, 0
        P.n_ord, P.l_ord, P.n_text = nil, nil, nil
        P.has_e, P.has_m, P.has_p, P.has_g, P.has_r = false, false, false, false, false
        P.nq, P.nd, P.n_empty_d, P.n_pos = 0, 0, 0, 0
        P.cpos, P.ctext, P.cmd_start, P.ord_text = nil, nil, nil, false
        P.fast_sh, P.fast_hit, P.fast_sum = nil, false, nil
        P.odd, P.limit = false, false
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

    -- A fast pattern's captures (the values, then the checksum text) into VV and pr_*; the
    -- checksum as the layout's fixed sum plus the values' sums (speed trick, measured).  Returns
    -- the number of values.
    local function take_fast_values(layout, c1, c2, c3, c4, c5, c6, c7, c8, c9)
        VV[1], VV[2], VV[3], VV[4], VV[5], VV[6], VV[7], VV[8], VV[9] = c1, c2, c3, c4, c5, c6, c7, c8, c9
        local n = layout.n
        P.ctext = VV[n + 1]
        local sum = layout.fixed
        for k = 1, n do sum = sum + str_sum(VV[k]) end
        P.fast_sum = sum % 256
        P.n_ord = layout.ord
        return n
    end

    -- The fields' places in a frame a fast path parsed (N, T/Q/D triplets or D fields, C), for
    -- a shown tree: the layout fixes every field but the values, whose lengths place the rest.
    function fast_positions(ntext, n, named)
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
        FL[i + 1], FS[i + 1], FE[i + 1] = L_C, p, p + #P.ctext
        P.nf = i + 1
    end

    -- Fast path: a frame with the layout of one of the node pair's
    -- recent plain named frames is matched by one anchored pattern.  mru: the pair's layouts,
    -- most recently matched first (a compressed stream's deltas cycle through a few subsets of
    -- the variables): a layout that does not fit fails within the first differing name, cheaply.
    -- Returns true when it parsed the frame.
    local function parse_fast_named(f, mru, rec_fields)
        local _, sh, c1, c2, c3, c4, c5, c6, c7, c8, c9
        for k = 1, #mru do
            sh = mru[k]
            _, _, c1, c2, c3, c4, c5, c6, c7, c8, c9 = s_find(f, sh.pat)
            if c1 then
                if k > 1 then table.remove(mru, k); table.insert(mru, 1, sh) end
                break
            end
        end
        if not c1 then return false end
        local n = take_fast_values(sh, c1, c2, c3, c4, c5, c6, c7, c8, c9)
        local st, sn = sh.T, sh.N
        local idx = sh.ord
        for k = 1, n do
            VT[k], VN[k], VI[k], VR[k] = st[k], sn[k], idx, false
            idx = idx + 1
        end
        P.nv, P.nq, P.nd = n, n, n
        P.fast_sh, P.fast_hit = sh, sh
        if rec_fields then fast_positions(sh.ntext, n, true) end
        return true
    end

    -- The same for the pair's last plain positional frame (N, D fields, C).
    local function parse_fast_positional(f, ps, rec_fields)
        local _, _, c1, c2, c3, c4, c5, c6, c7, c8, c9 = s_find(f, ps.pat)
        if not c1 then return false end
        local n = take_fast_values(ps, c1, c2, c3, c4, c5, c6, c7, c8, c9)
        local idx = ps.ord
        local n_empty_d = 0
        for k = 1, n do
            VT[k], VN[k], VI[k], VR[k] = false, false, idx, false
            idx = idx + 1
            if VV[k] == "" then n_empty_d = n_empty_d + 1 end
        end
        P.nv, P.nd, P.n_pos, P.n_empty_d = n, n, n, n_empty_d
        P.fast_hit = ps
        if rec_fields then fast_positions(ps.ntext, n, false) end
        return true
    end

    -- The plain path: every field from p on, in one pass (fields recorded with their positions
    -- when a tree is built), variables gathered as T/Q/R/D come; results in P.
    -- An N or L field's text as the tree shows it without an expert: a number 0 .. 2^32-1.
    local function ordinal_ok(text)
        local n = tonumber(text)
        return n and n >= 0 and n < 4294967296 and n == floor(n)
    end

    local function parse_general(f, p, bodyend, rec_fields)
        local n_ord, l_ord, n_text = nil, nil, nil
        local has_e, has_m, has_p, has_g, has_r = false, false, false, false, false
        local nq, nd, n_empty_d, n_pos = 0, 0, 0, 0
        local pend_t, pend_q, pend_r = false, false, false   -- pending T text, Q/R name
        local pend_tf, pend_qf = 0, 0
        local idx = 0
        local cpos, ctext = nil, nil  -- checksum field start and text
        local cmd_start = nil         -- first E/M field
        local ord_text = false        -- N or L with a non-numeric ordinal (N?, L?: a list request)
        local odd = false             -- a field with an expert info in the tree (see P.odd)
        while p and p <= bodyend + 1 do
            local c = s_byte(f, p)
            local _, fe, t1, t2, t3
            if c == L_T and not pend_q then
                _, fe, t1, t2, t3 = s_find(f, "^T([^]|]*)|Q([^]|]*)|D([^]|]*)", p)
            end
            if fe and fe <= bodyend then
                -- fast path: a complete T/Q/D triplet
                P.nv = P.nv + 1
                VT[P.nv], VN[P.nv], VV[P.nv], VI[P.nv], VR[P.nv] = t1, t2, t3, idx, false
                idx = idx + 1
                nq, nd = nq + 1, nd + 1
                if not valid_type(t1) then odd = true end
                if rec_fields then
                    local q1 = p + #t1 + 2
                    local d1 = q1 + #t2 + 2
                    FL[P.nf + 1], FS[P.nf + 1], FE[P.nf + 1] = L_T, p, q1 - 2
                    FL[P.nf + 2], FS[P.nf + 2], FE[P.nf + 2] = L_Q, q1, d1 - 2
                    FL[P.nf + 3], FS[P.nf + 3], FE[P.nf + 3] = L_D, d1, fe
                    VTf[P.nv], VQf[P.nv], VDf[P.nv] = P.nf + 1, P.nf + 2, P.nf + 3
                end
                P.nf = P.nf + 3
                pend_t = false
                p = fe + 2
            else
                _, fe, t1 = s_find(f, "^[^]|]([^]|]*)", p)
                if fe and fe > bodyend then fe = nil end
                if not fe then
                    -- empty field
                    P.nf = P.nf + 1
                    if rec_fields then FL[P.nf], FS[P.nf], FE[P.nf] = false, p, p - 1 end
                    odd = true
                    p = p + 1
                else
                    P.nf = P.nf + 1
                    if rec_fields then FL[P.nf], FS[P.nf], FE[P.nf] = c, p, fe end
                    if c == L_D then
                        nd = nd + 1
                        if not (has_e or has_m) then
                            P.nv = P.nv + 1
                            VT[P.nv], VN[P.nv], VV[P.nv], VI[P.nv], VR[P.nv] = pend_t, pend_q, t1, idx, pend_r
                            VTf[P.nv], VQf[P.nv], VDf[P.nv] = pend_tf, pend_qf, P.nf
                            if not pend_q then
                                n_pos = n_pos + 1
                                if t1 == "" then n_empty_d = n_empty_d + 1 end
                            end
                            idx = idx + 1
                            pend_t, pend_q, pend_r, pend_tf, pend_qf = false, false, false, 0, 0
                        end
                    elseif c == L_Q or c == L_R then
                        if pend_q then
                            P.nv = P.nv + 1
                            VT[P.nv], VN[P.nv], VV[P.nv], VI[P.nv], VR[P.nv] = pend_t, pend_q, false, idx, pend_r
                            VTf[P.nv], VQf[P.nv], VDf[P.nv] = pend_tf, pend_qf, 0
                            idx = idx + 1
                            pend_t, pend_tf = false, 0
                        end
                        pend_q, pend_qf = t1, P.nf
                        pend_r = (c == L_R)
                        if pend_r then has_r = true else nq = nq + 1 end
                    elseif c == L_T then
                        if pend_q then
                            P.nv = P.nv + 1
                            VT[P.nv], VN[P.nv], VV[P.nv], VI[P.nv], VR[P.nv] = pend_t, pend_q, false, idx, pend_r
                            VTf[P.nv], VQf[P.nv], VDf[P.nv] = pend_tf, pend_qf, 0
                            idx = idx + 1
                            pend_q, pend_r, pend_qf = false, false, 0
                        end
                        pend_t, pend_tf = t1, P.nf
                        if not valid_type(t1) then odd = true end
                    elseif c == L_N then
                        if not ordinal_ok(t1) then odd = true end
                        if #t1 > 9 and not s_find(t1, "[^0-9]") then
                            odd, P.limit = true, "Limit exceeded: N has more than 9 digits"
                        end
                        if not n_ord then
                            n_ord = to_ordinal(t1); idx = n_ord; n_text = t1
                            if not tonumber(t1) then ord_text = true end
                        end
                    elseif c == L_L then
                        if not ordinal_ok(t1) then odd = true end
                        if #t1 > 9 and not s_find(t1, "[^0-9]") then
                            odd, P.limit = true, "Limit exceeded: L has more than 9 digits"
                        end
                        if not l_ord then
                            l_ord = to_ordinal(t1); idx = l_ord
                            if not tonumber(t1) then ord_text = true end
                        end
                    elseif c == L_C and fe == bodyend then
                        cpos, ctext = p, t1
                    elseif c == L_E or c == L_M then
                        if c == L_E then has_e = true else has_m = true end
                        if not cmd_start then cmd_start = p end
                    elseif c == L_P then has_p = true
                    elseif c == L_G then has_g = true
                    else odd = true   -- an unknown letter, or C before the last field
                    end
                    p = fe + 2
                end
            end
        end
        if pend_q then
            P.nv = P.nv + 1
            VT[P.nv], VN[P.nv], VV[P.nv], VI[P.nv], VR[P.nv] = pend_t, pend_q, false, idx, pend_r
            VTf[P.nv], VQf[P.nv], VDf[P.nv] = pend_tf, pend_qf, 0
        end
        P.n_ord, P.l_ord, P.n_text = n_ord, l_ord, n_text
        P.has_e, P.has_m, P.has_p, P.has_g, P.has_r = has_e, has_m, has_p, has_g, has_r
        P.nq, P.nd, P.n_empty_d, P.n_pos = nq, nd, n_empty_d, n_pos
        P.cpos, P.ctext, P.cmd_start, P.ord_text = cpos, ctext, cmd_start, ord_text
        P.odd = odd
    end

    -- A named layout's code, made once per pattern (kept for 256 patterns): store(vals, from,
    -- num, v1, ..., vn) stores the values as the direction's last ones (the express lane), and
    -- info(v1, ..., vn) / dinfo(...) make the Info of a full frame / a delta (the express lane
    -- and info_frame).  Speed trick (measured): the names and the Info's pieces are constants in
    -- the code, one concatenation, nothing looked up.
    local LAYOUT_CODE, layout_code_n = {}, 0
    local function layout_code(pat, sn, pieces, dpieces)
        local code = LAYOUT_CODE[pat]
        if not code then
            local args, store, info, dinfo = {}, {}, {}, {}
            for k = 1, #sn do
                local q = string.format("%q", sn[k])
                args[k] = "v" .. k
                store[k] = "vals[" .. q .. "] = v" .. k .. " from[" .. q .. "] = num"
                info[2 * k - 1], info[2 * k] = string.format("%q", pieces[k]), args[k]
                dinfo[2 * k - 1], dinfo[2 * k] = string.format("%q", dpieces[k]), args[k]
            end
            local vs = t_concat(args, ", ")
            code = { assert(load("return function(vals, from, num, " .. vs .. ") " .. t_concat(store, " ") ..
                " end, function(" .. vs .. ") return " .. t_concat(info, " .. ") ..
                " end, function(" .. vs .. ") return " .. t_concat(dinfo, " .. ") .. " end",
                "=layout_code", "t", {}))() }
            if layout_code_n >= 256 then LAYOUT_CODE, layout_code_n = {}, 0 end
            LAYOUT_CODE[pat], layout_code_n = code, layout_code_n + 1
        end
        return code[1], code[2], code[3]
    end

    -- Remember the layout of a plain named frame (N, T/Q/D triplets, C) for parse_fast_named.
    local function learn_named_shape(f, shape_key, dstb, srcb)
        local n_text, cpos, n_pos, ord_text, n_ord = P.n_text, P.cpos, P.n_pos, P.ord_text, P.n_ord
        if shape_key and n_text and cpos and P.nv >= 1 and P.nv <= 8 and P.nf == 3 * P.nv + 2 and n_pos == 0
            and s_byte(f, 6) == L_N and not ord_text then
            local ok = true
            for k = 1, P.nv do
                if not (VT[k] and VN[k] and VV[k] and valid_type(VT[k])) or VR[k] then ok = false; break end
            end
            if ok then
                local parts = { "^%[:", pat_escape(LETTER[dstb] .. LETTER[srcb]), "|N", pat_escape(n_text) }
                -- the express lane's: the head (up to the first value) as plain text, the rest a
                -- pattern anchored where the head ends
                local xparts = {}
                local st, sn, tv = {}, {}, {}
                local head = LETTER[srcb] .. ARROW .. LETTER[dstb] .. " full"
                local dhead = LETTER[srcb] .. ARROW .. LETTER[dstb] .. " delta"
                local first = " " .. s_gsub(VN[1], CTRL, "?") .. "="
                local pieces, ilen = { head .. first }, #head
                local fixed = byte_sum(f, 2, cpos)
                for k = 1, P.nv do
                    st[k], sn[k], tv[k] = VT[k], VN[k], valid_type(VT[k])
                    local tq = "|T" .. pat_escape(VT[k]) .. "|Q" .. pat_escape(VN[k])
                    parts[#parts + 1] = tq .. "|D" .. VALUE
                    xparts[#xparts + 1] = (k > 1 and tq .. "|D" or "^") .. (tv[k] == 2 and XDOUBLE or XVALUE)
                    if k > 1 then pieces[k] = " " .. s_gsub(VN[k], CTRL, "?") .. "=" end
                    ilen = ilen + #VN[k] + 2
                    fixed = fixed - str_sum(VV[k])
                end
                parts[#parts + 1] = "|C([^]|]*)%]"
                xparts[#xparts + 1] = XCHECKSUM
                local mru = LY.named[shape_key]
                if not mru then mru = {}; LY.named[shape_key] = mru end
                local pat = t_concat(parts)
                -- a layout known already comes first again, the same table: everything in it
                -- follows from the pattern, and the direction's names_is compares the table's N
                for k = 1, #mru do
                    if mru[k].pat == pat then
                        if k > 1 then table.insert(mru, 1, table.remove(mru, k)) end
                        return
                    end
                end
                LY.xlen, LY.xlen_n = {}, 0
                if #mru >= MAX_SHAPES then mru[#mru] = nil end
                local dpieces = { dhead .. first }
                for k = 2, P.nv do dpieces[k] = pieces[k] end
                local xstore, xinfo, xdinfo = layout_code(pat, sn, pieces, dpieces)
                table.insert(mru, 1, { pat = pat, n = P.nv, T = st, N = sn, TV = tv, ord = n_ord, ntext = n_text,
                    xstore = xstore, xinfo = xinfo, xdinfo = xdinfo,
                    info_len = ilen, dinfo_len = ilen + #dhead - #head,
                    fixed = fixed % 256, letters = LETTER[srcb] .. LETTER[dstb],
                    xhead = "[:" .. LETTER[dstb] .. LETTER[srcb] .. "|N" .. n_text .. "|T" .. VT[1] .. "|Q" .. VN[1]
                        .. "|D",
                    xpat = t_concat(xparts), sums = EXPRESS_SUMS[P.nv] })
            end
        end
    end

    -- Remember the layout of a plain positional frame (N, D fields, C) for parse_fast_positional.
    local function learn_positional_shape(f, shape_key, dstb, srcb)
        local n_text, cpos, n_pos, nq, has_r = P.n_text, P.cpos, P.n_pos, P.nq, P.has_r
        local ord_text, n_ord = P.ord_text, P.n_ord
        if shape_key and n_text and cpos and P.nv >= 1 and P.nv <= 8 and P.nf == P.nv + 2 and n_pos == P.nv and nq == 0
            and not has_r and s_byte(f, 6) == L_N and not ord_text then
            local ok = true
            for k = 1, P.nv do
                if VT[k] or VN[k] or not VV[k] then ok = false; break end
            end
            if ok then
                local pat = "^%[:" .. pat_escape(LETTER[dstb] .. LETTER[srcb]) .. "|N" .. pat_escape(n_text) ..
                    s_rep("|D" .. VALUE, P.nv) .. "|C([^]|]*)%]"
                local ps = LY.pos[shape_key]
                if not ps or ps.pat ~= pat then
                    local fixed = byte_sum(f, 2, cpos)
                    for k = 1, P.nv do fixed = fixed - str_sum(VV[k]) end
                    LY.pos[shape_key] = { pat = pat, n = P.nv, ord = n_ord, ntext = n_text, fixed = fixed % 256 }
                end
            end
        end
    end

    -- Remember the layout of a bare frame (N0 and C only: every variable carried) for the
    -- express lane alone (see express).
    local function bare_sums(ctext) return 0, 0, ctext end
    local function bare_store() end
    local function learn_bare_shape(f, shape_key, dstb, srcb)
        local n_text, cpos = P.n_text, P.cpos
        if P.nv == 0 and P.nf == 2 and n_text and cpos and P.n_ord == 0 and not P.ord_text and s_byte(f, 6) == L_N then
            local xhead = "[:" .. LETTER[dstb] .. LETTER[srcb] .. "|N" .. n_text
            local bs = LY.bare[shape_key]
            if not bs or bs.xhead ~= xhead then
                LY.xlen, LY.xlen_n = {}, 0
                local dhead = LETTER[srcb] .. ARROW .. LETTER[dstb] .. " delta"
                LY.bare[shape_key] = { xhead = xhead, xpat = "^" .. XCHECKSUM, n = 0, N = {}, ord = 0, ntext = n_text,
                    fixed = byte_sum(f, 2, cpos) % 256,
                    letters = LETTER[srcb] .. LETTER[dstb], info_len = 0, dinfo_len = #dhead,
                    sums = bare_sums, xstore = bare_store, xdinfo = function() return dhead end, bare = true }
            end
        end
    end

    -- Parse a frame: header, then a fast path when one fits, else every field.  Returns the last
    -- index of the content, the address bytes and why it is malformed (nil: it is not).
    function parse_frame(f, fl, terminated, vis, rec_fields)
        parse_reset()
        local bodyend, dstb, srcb, p, malformed_msg = parse_header(f, fl, terminated)
        local shape_key = nil
        if p == 6 and not malformed_msg and dstb >= B_A and dstb <= B_P and srcb >= B_A and srcb <= B_P then
            shape_key = dstb * 256 + srcb
            -- a shown tree (vis) needs the fields' places too
            local mru, ps = FAST and LY.named[shape_key], FAST and LY.pos[shape_key]
            if (mru and parse_fast_named(f, mru, vis)) or (ps and parse_fast_positional(f, ps, vis)) then
                if MARKS.fast then MARKS.fast_hit = true end
                return bodyend, dstb, srcb, malformed_msg
            end
        end
        if p then parse_general(f, p, bodyend, rec_fields) end
        -- positional slots and declared entries at or past max_slots (their state is dropped)
        if P.nv > 0 and VI[P.nv] >= cfg.LIM.max_slots and not P.limit then
            P.odd = true
            P.limit = "Limit exceeded: a slot or ordinal at or past " .. cfg.LIM.max_slots .. " (max_slots)"
        end
        -- layouts are learnt on a miss (a frame the fast paths did not take), from a frame whose
        -- fields carry no expert info
        if shape_key and not P.odd then
            learn_named_shape(f, shape_key, dstb, srcb)
            learn_positional_shape(f, shape_key, dstb, srcb)
            learn_bare_shape(f, shape_key, dstb, srcb)
        end
        return bodyend, dstb, srcb, malformed_msg
    end
end

-- Checksum verdict, before the state (a frame with a bad checksum changes no state): the
-- value of the checksum text (nil: not hex), the calculated value, the status (1 good, 0 bad,
-- 2 unverified; nil: no C field).
local function checksum_verdict(f, bodyend)
    local ctext = P.ctext
    if P.fast_hit then P.cpos = bodyend - #ctext end   -- the fast patterns end in |C<ctext>]
    local cpos = P.cpos
    if not cpos then return nil, nil, nil end
    local cs_val = checksum_value(ctext)
    if not cfg.validate then return cs_val, nil, 2 end
    local cs_calc = P.fast_sum or byte_sum(f, 2, cpos) % 256
    return cs_val, cs_calc, (cs_val == cs_calc) and 1 or 0
end

-- The kind the fields alone tell; a data frame (full or delta, told by the state) gives nil, true.
local function kind_of_fields(malformed_msg)
    if malformed_msg then return "malformed", false end
    if P.has_e or P.has_m then return "command", false end
    if P.has_p then return "ping", false end
    if P.has_g then return "pong", false end
    if P.has_r then return "reply", false end
    local nd, nq, ord_text = P.nd, P.nq, P.ord_text
    if nd == 0 and nq > 0 and (P.l_ord or P.n_ord) and not ord_text then return "declaration", false end
    if nd == 0 and (nq > 0 or ord_text) then return "query", false end
    if nd > 0 or P.n_ord then return nil, true end
    return "other", false
end

for k, v in pairs({ FL = FL, FS = FS, FE = FE, FV = FV, FC = FC, VT = VT, VN = VN, VV = VV, VI = VI, VR = VR,
    VTf = VTf, VQf = VQf, VDf = VDf }) do P[k] = v end
Pm.parse_frame, Pm.fast_positions, Pm.checksum_verdict, Pm.kind_of_fields, Pm.MARKS =
    parse_frame, fast_positions, checksum_verdict, kind_of_fields, MARKS
return Pm
