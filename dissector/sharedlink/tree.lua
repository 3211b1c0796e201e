-- SharedLink dissector module: tree, a frame's items: the compact tree nobody sees (its fields, no ranges or labels)
-- and the full one (every range and label).
-- Loaded by sharedlink.lua (load_module); Wireshark also runs every .lua file of a plugin folder's
-- subfolders as a plugin of its own: this file then does nothing.

local token, M = ...
if type(token) ~= "table" or token.sharedlink_module ~= true then return end

local U, cfg, wsapi, hf = M.util, M.prefs, M.wsapi, M.fields.hf
local UHEX = U.UHEX
local ei, sl, s_byte, s_sub = M.fields.ei, M.proto, string.byte, string.sub
local s_find, s_format, tonumber, tostring = string.find, string.format, tonumber, tostring
local floor, ARROW, B_CR, B_LF = math.floor, U.ARROW, U.B_CR, U.B_LF
local B_A, B_P, L_N, L_T = U.B_A, U.B_P, U.L_N, U.L_T
local L_Q, L_R, L_D, L_C = U.L_Q, U.L_R, U.L_D, U.L_C
local L_L, L_E, L_M, L_P = U.L_L, U.L_E, U.L_M, U.L_P
local L_G, LETTER, valid_type, parse_long = U.L_G, U.LETTER, U.valid_type, U.parse_long
local nstime_of, zrange, FL, FS = U.nstime_of, U.zrange, M.parse.P.FL, M.parse.P.FS
local FE, FV, FC, VT = M.parse.P.FE, M.parse.P.FV, M.parse.P.FC, M.parse.P.VT
local VN, VV, VI, VR = M.parse.P.VN, M.parse.P.VV, M.parse.P.VI, M.parse.P.VR
local VTf, VQf, VDf = M.parse.P.VTf, M.parse.P.VQf, M.parse.P.VDf

local P = M.parse.P
local list_type, VALUE = M.state.list_type, cfg.VALUE
local crlf_frames = true   -- see set_crlf_frames
local R = M.records
local CARRY, MISS = R.CARRY, R.MISS

-- The typed field is hidden: the Value line above it shows the same fact.  With no range
-- (a tree nobody sees) the item is added with its value only.
-- TreeItem's methods called through this table (speed trick, measured: -V 16 us a frame
-- less): ti:add(...) looks the method up through wslua's __index, a call into C, each time.
local TI = wsapi.TI   -- see wsapi (2)

local function add_typed_value(vt, range, vtype, text)
    local field, v
    if vtype == 2 then
        field, v = hf.var_double, tonumber(text)
        if not v then TI.add_proto_expert_info(vt, ei.var_badvalue, "Not a double: " .. text) end
    elseif vtype == 0 then
        field, v = hf.var_long, parse_long(text)
        if not v then TI.add_proto_expert_info(vt, ei.var_badvalue, "Not a long (int64): " .. text) end
    elseif vtype == 4 then
        field, v = hf.var_string, text
    end
    if v then
        if range then TI.set_hidden(TI.add(vt, field, range, v)) else TI.add(vt, field, v) end
    end
end

-- A variable's value as its own field, sharedlink.value.<name> (docs/fields-sharedlink.md,
-- "Filtering by variable"): a data frame's value of a name that has one, sent or carried, typed
-- as the field (a value that does not read as its type is left out).  Hidden: the Value line
-- shows it.  add(parent, field, value) adds the item (the compact tree's probe, or TI.add).
local function value_of(vf, text)
    local vtype = vf.vtype
    if vtype == 2 then return tonumber(text) end
    if vtype == 0 then return parse_long(text) end
    return text
end

local function value_item(vt, name, text)
    local vf = VALUE[name]
    if not vf or not text then return end
    local x = value_of(vf, text)
    if x ~= nil then TI.set_hidden(TI.set_generated(TI.add(vt, vf.field, x))) end
end

-- The expert of a positional value past a list learnt from a declaration (docs/fields-sharedlink.md,
-- "Names from an a-priori list": past a user's or the a-priori list a slot is #i, no warning).
local function past_the_list(vt, v, list)
    if list.decl then
        TI.add_proto_expert_info(vt, ei.var_unknown,
            "Positional value " .. VI[v] .. " is past the known list (" .. #list .. " variables)")
    end
end

local tree_compact_frame
do
-- Fields of a frame parsed by a fast path, for a tree nobody sees (a display filter,
-- coloring rules, a tap): the fields of the full tree with their values, without byte
-- ranges, labels or flags, which only a visible tree shows.  Speed trick (measured: each
-- TvbRange, label or flag is one more Lua-to-C call).  The full tree is built below.
-- vals: the frame's values; carry: carried values of its empty D fields (value, frame, ...);
-- miss: named variables left out (name, value, frame, ...), nmiss entries.
--
-- Only the fields somebody asked for are repeated per variable.  In a tree nobody sees,
-- Wireshark adds a field only when a filter, coloring rule or tap references it; for any
-- other it hands back the parent item (proto.c, TRY_TO_FAKE_THIS_ITEM), whose text is the
-- parent's text.  So the first item of each per-variable field in a frame tells whether the
-- field is referenced (its text differs from its parent's: a real item has its own label;
-- checked on 4.0, 4.4 and 4.6), and an unreferenced field is not added again for the
-- frame's other variables (about 18 fewer Lua-to-C calls in a beacon frame).  Decided
-- again in every frame, as the referenced fields change when the user changes a filter.
--
-- tshark (no GUI) keeps what it learnt for the whole pass, every field included: its filters,
-- taps and field extractors are all set before the first packet and a field Wireshark once
-- saw referenced stays referenced.  (tshark -2 primes the display filter in its first pass
-- too; the cache starts again with each pass all the same.)  The GUI learns again in
-- every frame: its display filter and coloring rules change while it runs, and it dissects
-- packet-list rows (coloring rules only) in the middle of a filter pass.  The environment
-- variable SHAREDLINK_PROBE_EACH_FRAME makes tshark do as the GUI (for the tests).
local REF = {}      -- field -> referenced (nil: not known yet)
local VAR_FIELDS = { hf.var, hf.ftype, hf.var_name, hf.var_index, hf.var_value, hf.var_double,
    hf.var_long, hf.var_string, hf.var_carried, hf.var_carried_from }
for _, vf in pairs(VALUE) do VAR_FIELDS[#VAR_FIELDS + 1] = vf.field end
local CACHE_REFS = wsapi.cache_refs
local ref_num, ref_visited = -1, nil   -- the frame and pass the cache was last used in
local UNKNOWN = {}  -- "the parent's text is not read yet"

-- Add field = value under parent (whose text is ptext, or UNKNOWN) unless the field is known
-- to be unreferenced; learn that on its first item.  Returns the item or nil.
local function ref_add(parent, ptext, field, value)
    local r = REF[field]
    if r == false then return nil end
    local it
    if value == nil then it = TI.add(parent, field) else it = TI.add(parent, field, value) end
    if r == nil then
        if ptext == UNKNOWN then ptext = parent.text end
        r = wsapi.referenced(it, ptext)
        REF[field] = r
    end
    return r and it or nil
end

-- Start a frame's compact tree: the learnt fields kept (tshark, the same pass) or forgotten.
-- Returns the text ref_add compares ti's children with.
local function ref_start(ti, num, visited)
    if CACHE_REFS then
        if visited ~= ref_visited or (num ~= ref_num and num ~= ref_num + 1) then
            for k in pairs(REF) do REF[k] = nil end
            ref_visited = visited
        end
        ref_num = num
        return UNKNOWN
    end
    for k = 1, #VAR_FIELDS do REF[VAR_FIELDS[k]] = nil end
    return ti.text
end

-- A field of the frame itself in the compact tree: learnt as the per-variable ones when the
-- cache is on, else always added (once a frame, a probe would cost as much as it saves).
local function frame_add(ti, ttext, field, value)
    if CACHE_REFS then return ref_add(ti, ttext, field, value) end
    return TI.add(ti, field, value)
end

-- A variable's item in the compact tree: its subtree, or ti itself when nobody asked for
-- sharedlink.var; and the text its children are compared with (var_text: a real variable
-- item's text, the same for all; reset each frame).
local var_text = nil
local function compact_var(ti, ttext)
    local vt = ref_add(ti, ttext, hf.var)
    if not vt then return ti, ttext end
    var_text = var_text or vt.text
    return vt, var_text
end

-- A value's sharedlink.value.<name> field (value_item) in the compact tree.
local function compact_value(vt, ptext, name, text)
    local vf = VALUE[name]
    if not vf or not text then return end
    local x = value_of(vf, text)
    if x ~= nil then ref_add(vt, ptext, vf.field, x) end
end

-- A carried value's fields: its value and frame when known.
local function compact_carried(vt, ptext, cv, cf, name)
    if cv then ref_add(vt, ptext, hf.var_value, cv); compact_value(vt, ptext, name, cv) end
    ref_add(vt, ptext, hf.var_carried, true)
    if cf then ref_add(vt, ptext, hf.var_carried_from, cf) end
end

-- A value's typed field (double, long, string) or its var.badvalue.
local function compact_typed(vt, ptext, vtype, val)
    if vtype == 2 then
        local x = tonumber(val)
        if x then ref_add(vt, ptext, hf.var_double, x)
        else TI.add_proto_expert_info(vt, ei.var_badvalue, "Not a double: " .. val) end
    elseif vtype == 0 then
        local x = parse_long(val)
        if x then ref_add(vt, ptext, hf.var_long, x)
        else TI.add_proto_expert_info(vt, ei.var_badvalue, "Not a long (int64): " .. val) end
    elseif vtype == 4 then
        ref_add(vt, ptext, hf.var_string, val)
    end
end

-- Variable v's name and index: a named one's place among the direction's names, a positional
-- one's name and type from the list.
local function var_name_index(v, list, d, num, fast_tv)
    local name, index = VN[v], VI[v]
    local vtype
    if name then
        vtype = fast_tv and fast_tv[v] or valid_type(VT[v])
        if d then
            local first = d.nfirst[name]
            index = (first and first <= num) and d.npos[name] or nil
        end
    else
        name = list[index + 1]
        vtype = list.t and list.t[index + 1]
    end
    return name, index, vtype
end

-- Variable v in the compact tree; ke: the carried values used so far (carry: value, frame, ...).
local function compact_variable(ti, ttext, v, list, d, num, carry, ke, fast_tv)
    local vt, ptext = compact_var(ti, ttext)
    local name, index, vtype = var_name_index(v, list, d, num, fast_tv)
    local val = VV[v]
    if VN[v] then ref_add(vt, ptext, hf.ftype, vtype) end
    if not name then
        name = "#" .. VI[v]
        past_the_list(vt, v, list)
    end
    ref_add(vt, ptext, hf.var_name, name)
    if index then ref_add(vt, ptext, hf.var_index, index) end
    if val ~= "" or VN[v] then
        ref_add(vt, ptext, hf.var_value, val)
        if vtype then compact_typed(vt, ptext, vtype, val) end
        compact_value(vt, ptext, name, val)
        return ke
    end
    local cv, cf = false, false
    if carry then cv, cf = carry[ke + 1], carry[ke + 2] end
    compact_carried(vt, ptext, cv, cf, name)
    return ke + 2
end

local function tree_compact(ti, ttext, dstb, srcb, kind, n_ord, nvars, list, d, num, carry, miss, nmiss, fast_tv)
    frame_add(ti, ttext, hf.dst, LETTER[dstb])
    frame_add(ti, ttext, hf.dst_node, dstb - B_A + 1)
    frame_add(ti, ttext, hf.src, LETTER[srcb])
    frame_add(ti, ttext, hf.src_node, srcb - B_A + 1)
    frame_add(ti, ttext, hf.kind, kind)
    frame_add(ti, ttext, hf.ordinal, n_ord)
    var_text = nil
    local ke = 0
    for v = 1, nvars do ke = compact_variable(ti, ttext, v, list, d, num, carry, ke, fast_tv) end
    for k = 1, nmiss, 3 do
        local name = miss[k]
        local vt, ptext = compact_var(ti, ttext)
        ref_add(vt, ptext, hf.var_name, name)
        local index = d and d.npos[name]
        if index then ref_add(vt, ptext, hf.var_index, index) end
        compact_carried(vt, ptext, miss[k + 1], miss[k + 2], name)
    end
end

-- The compact tree's last fields: sync, limits, checksum, line end.
local function compact_trailer(ti, ttext, rec, a, e, fl, s, cs_val, cs_calc, cs_status)
    local ctext = P.ctext
    if rec and rec.late then
        frame_add(ti, ttext, hf.sync_is_late, true)
        TI.add_proto_expert_info(ti, ei.sync_late)
    end
    if P.limit then TI.add_proto_expert_info(ti, ei.limit, P.limit) end
    if rec and rec.limit then TI.add_proto_expert_info(ti, ei.limit, rec.limit) end
    if cs_val then frame_add(ti, ttext, hf.checksum, cs_val) else frame_add(ti, ttext, hf.checksum_text, ctext) end
    if #ctext ~= 2 or s_find(ctext, "[^0-9A-F]") then TI.add_proto_expert_info(ti, ei.checksum_format) end
    if cfg.validate then
        frame_add(ti, ttext, hf.checksum_calc, cs_calc)
        frame_add(ti, ttext, hf.checksum_status, cs_status)
        if cs_status == 0 then TI.add_proto_expert_info(ti, ei.checksum_bad) end
    else
        frame_add(ti, ttext, hf.checksum_status, 2)
    end
    local b = a + fl - 1
    if crlf_frames and not (e == b + 2 and s_byte(s, b + 1) == B_CR and s_byte(s, b + 2) == B_LF) then
        TI.add_proto_expert_info(ti, ei.crlf_missing)
    end
end

-- The compact tree of a frame the layout cache parsed, nobody sees: its fields (tree_compact), the
-- sync and checksum fields and experts, without ranges or labels.
function tree_compact_frame(ti, a, e, fl, s, dstb, srcb, kind, list, d, num, visited, rec, ne, nm,
                                  cs_val, cs_calc, cs_status)
    local carry = rec or (ne > 0 and CARRY)
    local miss = rec and rec.miss
    local nmiss = miss and #miss or 0
    if not miss and nm > 0 then miss, nmiss = MISS, nm end
    local ttext = ref_start(ti, num, visited)
    -- the last argument: the types of the named layout, made when it was learnt
    tree_compact(ti, ttext, dstb, srcb, kind, P.n_ord, P.nv, list, d, num, carry, miss, nmiss,
        P.named and P.named.TV)
    compact_trailer(ti, ttext, rec, a, e, fl, s, cs_val, cs_calc, cs_status)
end

end

-- The full tree (shown: every range and label).
local tree_full
do
    local TC = {}   -- what the parts share, for the frame tree_full was given (reused)

    -- An address: "Destination: A (node 1)", the node number folded into the letter's line,
    -- its field kept for filters but hidden; an expert when it is not a letter A-P.
    -- Speed trick (measured, -V): the labels are made once a letter (ADDR_LABEL[what][b]).
    local ADDR_LABEL = { Destination = {}, Source = {} }
    local function tree_address(ti, tvb, off, b, letter, is_node, field, node_field, what)
        if not b then return end   -- cut short: no byte to point at
        local r = tvb(off, 1)
        if is_node then
            local labels = ADDR_LABEL[what]
            local label = labels[b]
            if not label then
                label = what .. ": " .. letter .. " (node " .. (b - B_A + 1) .. ")"
                labels[b] = label
            end
            TI.add(ti, field, r, letter, label)
            TI.set_hidden(TI.add(ti, node_field, r, b - B_A + 1))
        else
            TI.add_proto_expert_info(TI.add(ti, field, r, letter), ei.address_invalid,
                what .. " " .. letter .. " is not a letter A-P")
        end
    end

    -- The protocol line: "SharedLink Protocol, B→A full" (", bad checksum").  Speed trick
    -- (measured, -V): the item is added with its text, one call, and the texts of node pairs
    -- (both addresses A-P: nodes) are kept (HEAD_TEXT[kind][pair key]).
    local HEAD_TEXT = {}
    local function tree_proto_item(tree, range, kind, dstb, srcb, dst, src, cs_status, nodes)
        local bad = cs_status == 0
        local byk, hk = HEAD_TEXT[kind], nil
        if nodes then
            hk = (dstb * 256 + srcb) * 2 + (bad and 1 or 0)
            if byk then
                local text = byk[hk]
                if text then return TI.add(tree, sl, range, text) end
            end
        end
        local text = "SharedLink Protocol, " .. src .. ARROW .. dst .. " " .. kind .. (bad and ", bad checksum" or "")
        if hk then
            if not byk then byk = {}; HEAD_TEXT[kind] = byk end
            byk[hk] = text
        end
        return TI.add(tree, sl, range, text)
    end

    -- Its first lines: the protocol item, addresses, kind, malformed.
    local function tree_head(tc)
        local tvb, o, src, dst, kind = tc.tvb, tc.o, tc.src, tc.dst, tc.kind
        local dstb, srcb, malformed_msg, cs_status = tc.dstb, tc.srcb, tc.malformed_msg, tc.cs_status
        local dnode = dstb and dstb >= B_A and dstb <= B_P
        local snode = srcb and srcb >= B_A and srcb <= B_P
        local ti = tree_proto_item(tc.tree, tvb(tc.a - 1, tc.e - tc.a + 1), kind, dstb, srcb, dst, src, cs_status,
            dnode and snode)
        tc.ti = ti

        tree_address(ti, tvb, o + 3, dstb, dst, dnode, hf.dst, hf.dst_node, "Destination")
        tree_address(ti, tvb, o + 4, srcb, src, snode, hf.src, hf.src_node, "Source")
        TI.set_generated(TI.add(ti, hf.kind, kind))
        if malformed_msg then
            TI.add_proto_expert_info(ti, ei.malformed, malformed_msg)
        end
    end

    -- A variable's T field: its type, or an expert when it is not a number.
    local function full_type(tc, vt, v, tf)
        local tvb, o = tc.tvb, tc.o
        local vtype = valid_type(VT[v])
        if vtype then
            TI.add(vt, hf.ftype, tvb(o + FS[tf] + 1, FE[tf] - FS[tf]), vtype)
        else
            vt:add(tvb(o + FS[tf], FE[tf] - FS[tf] + 1), "Type (T): " .. tostring(VT[v] or ""))
                :add_proto_expert_info(ei.var_badvalue, "Type is not a number")
        end
        return vtype
    end

    -- A variable's name: the subtree's label, its field kept for filters, hidden.
    local function full_name(tc, vt, v, name)
        local tvb, o = tc.tvb, tc.o
        if VN[v] then
            local qf = VQf[v]
            local qr = tvb(o + FS[qf] + 1, FE[qf] - FS[qf])
            if VR[v] then TI.add(vt, hf.response, qr, name) end
            TI.set_hidden(TI.add(vt, hf.var_name, qr, name))
        else
            TI.set_hidden(TI.add(vt, hf.var_name, tvb(o + FS[VDf[v]], 1), name))
            if not tc.list[VI[v] + 1] then past_the_list(vt, v, tc.list) end
        end
    end

    -- An empty positional D: the value carried forward (the frame's next carried pair).
    local function full_carried(tc, vt, v, label)
        local ke = tc.ke
        local cv, cf = false, false
        local csrc = tc.rec or (tc.ne > 0 and CARRY)
        if csrc then cv, cf = csrc[ke + 1], csrc[ke + 2] end
        tc.ke = ke + 2
        local r0 = tc.tvb(tc.o + FS[VDf[v]], 1)
        if cv then
            TI.set_generated(TI.add(vt, hf.var_value, r0, cv))
            value_item(vt, label, cv)
        end
        TI.set_generated(TI.add(vt, hf.var_carried, r0, true))
        if cf then
            TI.set_generated(TI.add(vt, hf.var_carried_from, r0, cf))
            TI.set_text(vt, label .. " = " .. tostring(cv) .. " (carried from frame " .. cf .. ")")
        else
            TI.set_text(vt, label .. " = ? (carried, no earlier value)")
        end
    end

    -- A reply's link to its query (or the expert of a reply without one).
    local function full_reply(tc, vt, name)
        local resp_to, unmatched = tc.resp_to, tc.unmatched
        if resp_to and resp_to[name] then
            TI.set_generated(TI.add(vt, hf.response_to, resp_to[name]))
            TI.set_generated(TI.add(vt, hf.response_time, nstime_of(tc.rts[name])))
        elseif unmatched and unmatched[name] then
            TI.add_proto_expert_info(vt, ei.unanswered)
        end
    end

    -- A variable's value (its D), or what a declaration or a reply without value shows.
    local function full_value(tc, vt, v, name, label, vtype)
        local val = VV[v]
        if not val then
            TI.set_text(vt, label .. (VR[v] and " (reply without value)" or " (declared)"))
            local resp_in = tc.resp_in
            if resp_in and resp_in[name] then TI.set_generated(TI.add(vt, hf.response_in, resp_in[name])) end
            return
        end
        if val ~= "" or VN[v] then
            local df = VDf[v]
            local vr = tc.tvb(tc.o + FS[df] + 1, FE[df] - FS[df])
            TI.add(vt, hf.var_value, vr, val)
            if vtype then add_typed_value(vt, vr, vtype, val) end
            if not VR[v] then value_item(vt, name, val) end
            TI.set_text(vt, label .. " = " .. val)
        else
            full_carried(tc, vt, v, label)
        end
        if VR[v] then full_reply(tc, vt, name) end
    end

    -- A variable's subtree, at its first field fs.
    local function tree_variable(tc, v, fs)
        local list, d = tc.list, tc.d
        local tf, qf, df = VTf[v], VQf[v], VDf[v]
        local vend = df ~= 0 and df or (qf ~= 0 and qf or tf)
        local name = VN[v]
        local index = VI[v]
        local vtype = nil
        if not name then
            name = list[index + 1] or ("#" .. index)
            vtype = list.t and list.t[index + 1]
        elseif VR[v] then
            -- a reply's value: typed by its T, else by the list its direction uses
            vtype = list_type(list, name)
        elseif d then
            -- a named variable's index: its place among the conversation's names
            local first = d.nfirst[name]
            index = (first and first <= tc.num) and d.npos[name] or nil
        end
        local vt = TI.add(tc.ti, hf.var, tc.tvb(tc.o + fs, FE[vend] - fs + 1))
        if tf ~= 0 then vtype = full_type(tc, vt, v, tf) end
        full_name(tc, vt, v, name)
        if not VR[v] and index then TI.set_generated(TI.add(vt, hf.var_index, index)) end
        full_value(tc, vt, v, name, name or ("#" .. VI[v]), vtype)
    end

    -- An N, L or T field (letter l, text at f[fs+1..fe]): its number, or an expert when it is none.
    local function full_number_field(tc, l, fs, fe, text, vr)
        local ti, tvb, o = tc.ti, tc.tvb, tc.o
        if l == L_T then
            local t = valid_type(text)
            if t then
                TI.add(ti, hf.ftype, vr, t)
            else
                ti:add(tvb(o + fs, fe - fs + 1), "Type (T): " .. text)
                    :add_proto_expert_info(ei.var_badvalue, "Type is not a number")
            end
            return
        end
        local n = tonumber(text)
        if n and n >= 0 and n < 4294967296 and n == floor(n) then
            TI.add(ti, l == L_N and hf.ordinal or hf.inbound_ordinal, vr, floor(n))
        else
            ti:add(tvb(o + fs, fe - fs + 1), (l == L_N and "Ordinal (N): " or "Inbound ordinal (L): ") ..
                text):add_proto_expert_info(ei.var_badvalue, "Ordinal is not a number")
        end
    end

    -- A field of an unknown letter (or a C that is not the last field).
    local function full_unknown_field(tc, l, fs, fe)
        local tvb, o = tc.tvb, tc.o
        local ft = TI.add(tc.ti, hf.field_letter, tvb(o + fs, 1), LETTER[l])
        TI.add(ft, hf.field_text, tvb(o + fs, fe - fs + 1), s_sub(tc.f, fs, fe))
        if l == L_C then
            TI.add_proto_expert_info(ft, ei.field_unknown, "Checksum field C that is not the last field")
        else
            TI.add_proto_expert_info(ft, ei.field_unknown, "Unknown field letter " .. LETTER[l])
        end
    end

    -- the plain fields by letter: their field (E: the command, whose D arguments follow it)
    local PLAIN = { [L_R] = hf.response, [L_E] = hf.command, [L_M] = hf.mode, [L_P] = hf.ping, [L_G] = hf.pong }

    -- A field that is not part of a variable (letter l, f[fs..fe]).
    local function tree_plain_field(tc, l, fs, fe)
        local ti, tvb, o, resp_in = tc.ti, tc.tvb, tc.o, tc.resp_in
        local text = (l ~= false) and s_sub(tc.f, fs + 1, fe) or ""
        local vr = tvb(o + fs + 1, fe - fs)     -- the text after the letter
        if l == false then
            TI.add_proto_expert_info(TI.add(ti, zrange(tvb, o + fs), "Empty field"), ei.field_empty)
        elseif l == L_N or l == L_L or l == L_T then
            full_number_field(tc, l, fs, fe, text, vr)
        elseif l == L_Q then
            local qt = TI.add(ti, hf.query, vr, text)
            if resp_in and resp_in[text] then
                TI.set_generated(TI.add(qt, hf.response_in, resp_in[text]))
            end
        elseif PLAIN[l] then
            local item = TI.add(ti, PLAIN[l], vr, text)
            if l == L_E then tc.cmd_item = item end
        elseif l == L_D then
            (tc.cmd_item or ti):add(hf.command_arg, vr, text)
        else
            full_unknown_field(tc, l, fs, fe)
        end
    end

    -- The fields in order; a variable is rendered at its first field.
    local function tree_fields(tc)
        local kind, cpos = tc.kind, P.cpos
        for i = 1, P.nf do FV[i] = 0; FC[i] = false end
        for v = 1, P.nv do
            if VV[v] or kind == "declaration" or VR[v] then
                local first = VTf[v] ~= 0 and VTf[v] or (VQf[v] ~= 0 and VQf[v] or VDf[v])
                FV[first] = v
                if VQf[v] ~= 0 and VQf[v] ~= first then FC[VQf[v]] = true end
                if VDf[v] ~= 0 and VDf[v] ~= first then FC[VDf[v]] = true end
            end
        end
        for i = 1, P.nf do
            local fs = FS[i]
            local v = FV[i]
            if v ~= 0 then
                tree_variable(tc, v, fs)
            elseif not FC[i] and fs ~= cpos then
                tree_plain_field(tc, FL[i], fs, FE[i])
            end
        end
    end

    -- A list request's link to the declaration that answers it, and back (docs/fields-sharedlink.md,
    -- "Replies": L? is answered by an N declaration, N? by an L one).
    local function tree_request_link(tc)
        local rec, ti = tc.rec, tc.ti
        if rec.req_in then TI.set_generated(TI.add(ti, hf.response_in, rec.req_in)) end
        if rec.req_to then
            TI.set_generated(TI.add(ti, hf.response_to, rec.req_to))
            TI.set_generated(TI.add(ti, hf.response_time, nstime_of(rec.req_rt)))
        end
    end

    -- Named variables this frame left out (carried forward).
    local function tree_carried_names(tc)
        local ti, tvb, o, rec, nm, d, bodyend = tc.ti, tc.tvb, tc.o, tc.rec, tc.nm, tc.d, tc.bodyend
        -- carried named variables (left out of this frame)
        local miss = rec and rec.miss
        local miss_len = miss and #miss or 0
        if not miss and nm > 0 then miss, miss_len = MISS, nm end    -- packed on this pass
        if miss then
            for k = 1, miss_len, 3 do
                local name, cv, cf = miss[k], miss[k + 1], miss[k + 2]
                local vt = TI.add(ti, hf.var, zrange(tvb, o + bodyend))
                TI.set_hidden(TI.add(vt, hf.var_name, name))
                local index = d and d.npos[name]
                if index then TI.set_generated(TI.add(vt, hf.var_index, index)) end
                if cv then
                    TI.set_generated(TI.add(vt, hf.var_value, cv))
                    value_item(vt, name, cv)
                end
                TI.set_generated(TI.add(vt, hf.var_carried, true))
                if cf then
                    TI.set_generated(TI.add(vt, hf.var_carried_from, cf))
                    TI.set_text(vt, name .. " = " .. tostring(cv) .. " (carried from frame " .. cf .. ")")
                else
                    TI.set_text(vt, name .. " = ? (carried, no earlier value)")
                end
                TI.set_generated(vt)
            end
        end
    end

    -- The checksum field (at cpos, text ctext), its verdict and experts.
    local CHECKSUM_OK = {}   -- value -> "Checksum: 0x.. [correct]"
    local function full_checksum(tc, cpos, ctext)
        local ti, cs_val, cs_calc, cs_status = tc.ti, tc.cs_val, tc.cs_calc, tc.cs_status
        local cr = tc.tvb(tc.o + cpos, #ctext + 1)
        local val = cs_val
        local ct
        local byte_val = val and val <= 255
        if byte_val and cfg.validate and cs_status == 1 then
            -- the label with " [correct]", one call (speed trick, measured: -V)
            local label = CHECKSUM_OK[val]
            if not label then
                label = s_format("Checksum: 0x%02x [correct]", val)
                CHECKSUM_OK[val] = label
            end
            ct = TI.add(ti, hf.checksum, cr, val, label)
        elseif byte_val then
            ct = TI.add(ti, hf.checksum, cr, val)
        else
            ct = TI.add(ti, hf.checksum_text, cr, ctext)
        end
        if #ctext ~= 2 or s_find(ctext, "[^0-9A-F]") then
            TI.add_proto_expert_info(ct, ei.checksum_format, "Checksum \"" .. ctext ..
                "\" is not two upper-case hex digits")
        end
        if not cfg.validate then
            TI.set_generated(TI.add(ct, hf.checksum_status, cr, 2))
            return
        end
        TI.set_generated(TI.add(ct, hf.checksum_calc, cr, cs_calc))
        if cs_status == 1 then
            TI.set_generated(TI.add(ct, hf.checksum_status, cr, 1))
            if not byte_val then TI.append_text(ct, " [correct]") end
        else
            TI.set_generated(TI.add(ct, hf.checksum_status, cr, 0))
            TI.append_text(ct, s_format(" [incorrect, should be 0x%02x]", cs_calc))
            TI.add_proto_expert_info(ct, ei.checksum_bad, s_format("Bad checksum: %s, calculated %02X", ctext, cs_calc))
        end
    end

    -- Its last lines: limits, sync, checksum, line terminator.
    local function tree_trailer(tc)
        local ti, rec, s, a, e, fl = tc.ti, tc.rec, tc.s, tc.a, tc.e, tc.fl
        local terminated = tc.terminated
        if P.limit then TI.add_proto_expert_info(ti, ei.limit, P.limit) end
        if rec and rec.limit then TI.add_proto_expert_info(ti, ei.limit, rec.limit) end
        if rec and rec.late then
            TI.set_generated(TI.add(ti, hf.sync_is_late, true))
            TI.add_proto_expert_info(ti, ei.sync_late,
                s_format("No full frame for %.3f s (sync interval %.3f s + %.1f s slack)",
                    rec.late, cfg.sync - U.SYNC_SLACK, U.SYNC_SLACK))
        end
        if P.cpos then
            full_checksum(tc, P.cpos, P.ctext)
        else
            TI.set_generated(TI.add(ti, hf.checksum_status, 2))
            if terminated and not tc.malformed_msg then TI.add_proto_expert_info(ti, ei.checksum_missing) end
        end
        -- line terminator
        local b = a + fl - 1
        if terminated and crlf_frames
            and not (e == b + 2 and s_byte(s, b + 1) == B_CR and s_byte(s, b + 2) == B_LF) then
            TI.add_proto_expert_info(ti, ei.crlf_missing)
        end
    end

    -- The whole of it, for a frame at f[1..fl] (bodyend: its content's last index) that starts at
    -- s[a] and ends with its line end at s[e] (as dissect_frame's arguments), as parsed (the
    -- field and variable arrays, P.cpos, P.ctext), with its kind, state and checksum verdict.
    -- Called by dissect_frame; what the parts share goes in TC.
    function tree_full(tree, tvb, f, s, a, e, fl, terminated, bodyend, malformed_msg, num, kind, dstb, srcb,
                       list, d, rec, ne, nm, cs_val, cs_calc, cs_status)
        local tc = TC
        -- tvb offset of f[i] is o + i
        tc.tree, tc.tvb, tc.o, tc.f, tc.s, tc.a, tc.e, tc.fl = tree, tvb, a - 2, f, s, a, e, fl
        tc.num, tc.kind, tc.dstb, tc.srcb = num, kind, dstb, srcb
        tc.dst, tc.src = dstb and LETTER[dstb] or "?", srcb and LETTER[srcb] or "?"
        tc.malformed_msg, tc.terminated, tc.bodyend = malformed_msg, terminated, bodyend
        tc.list, tc.d, tc.rec, tc.ne, tc.nm = list, d, rec, ne, nm
        tc.cs_val, tc.cs_calc, tc.cs_status = cs_val, cs_calc, cs_status
        tc.resp_in, tc.resp_to = rec and rec.resp_in, rec and rec.resp_to
        tc.rts, tc.unmatched = rec and rec.rt, rec and rec.unmatched
        tc.ke, tc.cmd_item = 0, nil   -- carried values of empty D fields used so far; the E field's item
        tree_head(tc)
        tree_fields(tc)
        if rec and (rec.req_in or rec.req_to) then tree_request_link(tc) end
        tree_carried_names(tc)
        tree_trailer(tc)
    end
end

-- Whether a variable's value would get var.badvalue or var.unknown (see has_experts).
-- A frame of a named layout: its types are valid and its doubles plain decimals (the layout's
-- pattern), so only a long can fail (speed trick, measured: tonumber on a value is ~1,150
-- instructions).
local function named_values_have_experts(tv)
    for v = 1, P.nv do
        if tv[v] == 0 and not parse_long(VV[v]) then return true end
    end
    return false
end

-- Variable v's type for has_experts, or true when its name or T already has an expert.
local function expert_type(v, list)
    if VN[v] then
        if VT[v] then return valid_type(VT[v]) or true end
        return VR[v] and list_type(list, VN[v]) or nil
    end
    if not list[VI[v] + 1] and list.decl then return true end
    return list.t[VI[v] + 1]
end

local function values_have_experts(kind, list)
    local named = P.named
    if named then return named.has_long and named_values_have_experts(named.TV) end
    for v = 1, P.nv do
        local val = VV[v]
        if val or kind == "declaration" or VR[v] then
            local vtype = expert_type(v, list)
            if vtype == true then return true end
            if val and vtype and (val ~= "" or VN[v]) then
                if vtype == 2 then
                    if not tonumber(val) then return true end
                elseif vtype == 0 and not parse_long(val) then
                    return true
                end
            end
        end
    end
    return false
end

-- With no tree, whether the frame's tree would carry an expert info (true when unsure): then
-- the tree is built all the same, on the tree Wireshark gave (which keeps no items but reports
-- the experts to Expert Information and -z expert).  Checks what tree_full adds experts for.
local function has_experts(s, a, e, fl, terminated, malformed_msg, addrs_ok, kind, list, rec, cs_status)
    if malformed_msg or not addrs_ok or P.odd or cs_status == 0 or not P.cpos then return true end
    if rec and (rec.limit or rec.late or rec.unmatched) then return true end
    local ctext = P.ctext
    if not UHEX[ctext] then return true end   -- not two upper-case hex digits
    local b = a + fl - 1
    if terminated and crlf_frames and not (e == b + 2 and s_byte(s, b + 1) == B_CR and s_byte(s, b + 2) == B_LF) then
        return true
    end
    return values_have_experts(kind, list)
end

-- Whether CR LF frames the bytes of the packet being dissected (docs/fields-sharedlink.md, "Rules
-- for real sessions": serial and TCP, not a UDP datagram, which is one frame or several each
-- ending at its ']'): sharedlink.crlf.missing is noted only then.  Set once a packet.
local function set_crlf_frames(v) crlf_frames = v end

local T = { tree_compact_frame = tree_compact_frame, tree_full = tree_full, has_experts = has_experts,
            set_crlf_frames = set_crlf_frames }
return T
