-- SharedLink dissector module: tree, a frame's items, one builder for every tree: shown (every range,
-- label and flag), hidden (a tree nobody sees: the values of the fields somebody references) and none
-- (no tree at all: the expert infos alone).
-- Run by sharedlink.lua the first time a frame's tree is built (load_tree; the expert conditions
-- and the trees' modes are experts.lua's); Wireshark also runs every .lua file of a plugin folder's
-- subfolders as a plugin of its own: this file then does nothing.

local token, M = ...
if type(token) ~= "table" or token.sharedlink_module ~= true then return end

local U, cfg, wsapi, hf = M.util, M.prefs, M.wsapi, M.fields.hf
local ei, sl, s_sub = M.fields.ei, M.proto, string.sub
-- (the rarely used ones, string.format, tostring, U.ARROW, U.nstime_of, U.zrange, read where used:
-- the main chunk keeps under 150 locals)
local tonumber = tonumber
local floor = math.floor
local B_A = U.B_A
local LETTER, valid_type, parse_long = U.LETTER, U.valid_type, U.parse_long
local F = M.parse.F   -- the frame record (parse.lua): tree_frame's argument
local FL, FS, FE, FV, FC, VT = F.FL, F.FS, F.FE, F.FV, F.FC, F.VT
local VN, VV, VI, VR = F.VN, F.VV, F.VI, F.VR
local VTf, VQf, VDf, slot_name = F.VTf, F.VQf, F.VDf, U.slot_name
local VALUE = cfg.VALUE   -- name -> its value field (sharedlink.value.<name>), made at load
local CARRY, MISS = M.records.CARRY, M.records.MISS

-- TreeItem's methods called through wsapi.TI (speed trick, measured: -V 16 us a frame less):
-- ti:add(...) looks the method up through wslua's __index, a call into C, each time.  Kept here
-- as upvalues (speed trick, measured: -V, one table read less a call, ~90 a frame), taken once
-- wsapi.init has checked them on the first packet (bind_ti, called by tree_frame).
local TI = wsapi.TI   -- see wsapi (2)
local ti_add, ti_hide, ti_gen, ti_text, ti_append, ti_expert, ti_ref   -- (ti_ref: wsapi.referenced)
local ti_bound = false
local function bind_ti()
    ti_add, ti_hide, ti_gen, ti_text = TI.add, TI.set_hidden, TI.set_generated, TI.set_text
    ti_append, ti_expert = TI.append_text, TI.add_proto_expert_info
    ti_ref = wsapi.referenced
    ti_bound = wsapi.ready
end

------------------------------------------------------------------------------
-- One builder, three trees.  tree_frame walks the frame's items once, in the order a shown tree
-- has them: the head (protocol item, addresses, kind), the fields in order (a variable at its
-- first field: tree_variable, the one place a variable's items are made), the named variables
-- the frame left out, the trailer (limits, sync, checksum, line end).  Each item is made in one
-- of three ways, by the mode of the frame's tree:
--   SHOWN   (-V, PDML, -T fields, the GUI's details): with its byte range, label and flags;
--   HIDDEN  (a tree nobody sees: -Y, coloring rules, taps): its value alone, no range, label or
--           flag (each is one more call into C), and not at all when nobody references its
--           field (REF, below); an item's children go on the nearest item that was made;
--   NONE    (no tree at all: tshark's summary pass, the GUI opening a file): no item; built only
--           for a frame with expert infos (has_experts), which are added in every mode, on the
--           nearest item (Wireshark's convention: Expert Information and -z expert need no tree).
-- Speed trick (measured, -Y): a hidden tree skips what nobody references, and the values of
-- unreferenced fields are not even computed (a double's tonumber is ~1,150 instructions).
------------------------------------------------------------------------------
-- the fields used most, as upvalues (a table's field is a hash lookup: speed trick, measured)
local H_var, H_ftype, H_var_name, H_var_index, H_var_value, H_var_double, H_var_carried =
    hf.var, hf.ftype, hf.var_name, hf.var_index, hf.var_value, hf.var_double, hf.var_carried
local H_var_carried_from, H_checksum, H_checksum_calc, H_checksum_status, H_ordinal, H_dst, H_src =
    hf.var_carried_from, hf.checksum, hf.checksum_calc, hf.checksum_status, hf.ordinal, hf.dst, hf.src

local E = M.experts   -- the frame's expert conditions, the trees' modes (experts.lua)
local SHOWN, HIDDEN, NONE = E.SHOWN, E.HIDDEN, E.NONE
local X, frame_experts, values_have_experts = E.X, E.frame_experts, E.values_have_experts

-- Which fields somebody references: field -> true/false, asked of Wireshark (wsapi.referenced,
-- which answers true when unsure) the first time a frame's tree needs to know.  In a tree nobody
-- sees Wireshark adds a field only when the filters, coloring rules, custom columns, taps or
-- field extractors primed for that dissection reference it, and a dissection may be primed
-- otherwise than the one before it (a sharkd request's columns, the GUI's new column or coloring
-- rule, a pass's filter): what was asked is kept for the rest of the dissection (the frames of
-- one packet), and past it only over a first pass outside the GUI (wsapi.first_pass_fixed:
-- tshark's pass with its filters, taps and extractors fixed at start, or its -2's first pass),
-- where every dissection is primed alike.  Anything else asks again, so no field is ever lost
-- (docs/architecture.md, "The referenced-field cache").  A field is asked only where an item of
-- it is about to be made (REF[field] is read there), so the values of unreferenced fields are
-- not computed.  SHAREDLINK_PROBE_EACH_FRAME=1: asked again in every frame.
local LEARNT = {}
local NO_REF = {}     -- mode NONE: nothing is referenced
for _, field in pairs(hf) do NO_REF[field] = false end
local REF = LEARNT    -- the one in use for the frame being built
local EACH_FRAME = wsapi.env.probe_each_frame
local KEEP_FIRST_PASS = wsapi.first_pass_fixed and not EACH_FRAME
local ASKED, n_asked = {}, 0   -- the fields LEARNT holds, to forget them
local ref_tvb, ref_root, ref_kept = nil, nil, false   -- the dissection: its Tvb, its root; kept over a first pass
setmetatable(LEARNT, { __index = function(t, field)
    if field == nil then return nil end
    local r = ti_ref(ref_root, field)
    t[field] = r
    n_asked = n_asked + 1
    ASKED[n_asked] = field
    return r
end })

-- The fields a hidden data frame's tree always asks about (the head's, N's, a variable's, the
-- checksum's), asked at once when a hidden tree starts: a call each, not the metamethod's
-- (speed trick, measured: about 1.1k instructions a field less where every dissection asks).
-- They stay first in ASKED from one hidden start to the next (ask_first_in), so only the fields
-- asked after them are forgotten there: the always-asked ones are overwritten (speed trick,
-- measured: the GUI's rows).
local ASK_FIRST = { H_dst, hf.dst_node, H_src, hf.src_node, hf.kind, H_ordinal, H_var, H_var_name,
    H_var_index, H_var_value, H_ftype, H_var_double, H_checksum, H_checksum_calc, H_checksum_status }
-- ASKED.first: ASKED[1..#ASK_FIRST] holds ASK_FIRST (the last start was a hidden one's); ASKED.gen:
-- the number of the answers LEARNT holds (a start that forgets them adds one)
ASKED.first, ASKED.gen = false, 0
-- Whether the last hidden start found every ASK_FIRST field unreferenced (LEARNT holds the answers
-- until the next start): then a calm frame's hidden tree may be the protocol item alone (calm_unseen)
local first_unseen = false

-- Start a tree (shown or hidden): tvb, the packet's Tvb (the same object for the frames of one
-- packet: one dissection); tree, its root item; hidden, a hidden tree; first, of a first pass
-- (pinfo.visited false).  Forgets what was asked unless the dissection is primed as the last.
local function ref_start(tree, tvb, hidden, first)
    if rawequal(tvb, ref_tvb) and not EACH_FRAME then return end   -- the packet's next frame
    ref_tvb, ref_root = tvb, tree
    local keep = hidden and first and KEEP_FIRST_PASS
    if keep and ref_kept then return end   -- the same first pass: primed alike
    local learnt, asked, n_first = LEARNT, ASKED, #ASK_FIRST
    local was_first = asked.first
    for k = (hidden and was_first) and n_first + 1 or 1, n_asked do learnt[asked[k]] = nil end
    n_asked = 0
    ref_kept, asked.gen, asked.first = keep, asked.gen + 1, hidden
    first_unseen = false
    if hidden then
        local ask, unseen = ti_ref, true
        for k = 1, n_first do
            local field = ASK_FIRST[k]
            local r = ask(tree, field)
            learnt[field] = r
            if r then unseen = false end
        end
        first_unseen = unseen
        if not was_first then
            for k = 1, n_first do asked[k] = ASK_FIRST[k] end
        end
        n_asked = n_first
    end
end

-- A hidden item: field = value under parent when somebody references the field (REF), the
-- item; nil when nobody does.  (The callers of the commonest items check REF[field] first, so
-- an unreferenced field's value is not even computed.)
local function hadd(parent, field, value)
    if not REF[field] then return nil end
    if value == nil then return ti_add(parent, field) end
    return ti_add(parent, field, value)
end
local hitem = hadd

-- The frame being built (set by tree_frame; upvalues, not a table's fields: speed trick, measured)
local C = {}   -- the rest of it
local c_shown
local c_csrc, c_d, c_f, c_ke, c_list, c_num, c_o, c_places
local c_ti, c_tv, c_tvb

------------------------------------------------------------------------------
-- The head: the protocol item, the addresses, the kind, malformed.
------------------------------------------------------------------------------
-- An address: "Destination: A (node 1)", the node number folded into the letter's line, its field
-- kept for filters but hidden; an expert when it is not a letter A-P.  Speed trick (measured, -V):
-- the labels are made once a letter (ADDR_LABEL[what][b]).
local ADDR_LABEL = { Destination = {}, Source = {} }
local function tree_address(off, b, letter, is_node, field, node_field, what)
    if not b then return end   -- cut short: no byte to point at
    local ti = c_ti
    if c_shown then
        local r = c_tvb(off, 1)
        if is_node then
            local labels = ADDR_LABEL[what]
            local label = labels[b]
            if not label then
                label = what .. ": " .. letter .. " (node " .. (b - B_A + 1) .. ")"
                labels[b] = label
            end
            ti_add(ti, field, r, letter, label)
            ti_hide(ti_add(ti, node_field, r, b - B_A + 1))
            return
        end
        ti = ti_add(ti, field, r, letter)
    elseif is_node then
        if REF[field] ~= false then hadd(ti, field, letter) end
        if REF[node_field] ~= false then hadd(ti, node_field, b - B_A + 1) end
        return
    else
        ti = hitem(ti, field, letter) or ti
    end
    -- (one summary a problem, issue 41: the letter is in the field itself)
    ti_expert(ti, ei.address_invalid, what .. " is not a letter A-P")
end

-- The protocol line: "SharedLink Protocol, B→A full" (", bad checksum").  Speed trick (measured,
-- -V): the item is added with its text, one call, and the texts of node pairs (both addresses
-- A-P: nodes) are kept (HEAD_TEXT[kind][pair key]).
local HEAD_TEXT = {}
local function proto_item_text(kind, dstb, srcb, dst, src, cs_status, nodes)
    local bad = cs_status == 0
    local byk, hk = HEAD_TEXT[kind], nil
    if nodes then
        hk = (dstb * 256 + srcb) * 2 + (bad and 1 or 0)
        if byk then
            local text = byk[hk]
            if text then return text end
        end
    end
    local text = "SharedLink Protocol, " .. src .. U.ARROW .. dst .. " " .. kind .. (bad and ", bad checksum" or "")
    if hk then
        if not byk then byk = {}; HEAD_TEXT[kind] = byk end
        byk[hk] = text
    end
    return text
end

local function tree_head()
    local mode, tvb, kind, dstb, srcb = C.mode, c_tvb, C.kind, C.dstb, C.srcb
    local dnode, snode = dstb ~= nil and not X.dst_invalid, srcb ~= nil and not X.src_invalid
    local ti
    if mode == SHOWN then
        ti = ti_add(C.tree, sl, tvb(C.a - 1, C.e - C.a + 1),
            proto_item_text(kind, dstb, srcb, C.dst, C.src, C.cs_status, dnode and snode))
    elseif mode == HIDDEN then
        ti = ti_add(C.tree, sl, tvb(C.a - 1, C.e - C.a + 1))
    else
        ti = ti_add(C.tree, sl)
    end
    c_ti = ti
    tree_address(c_o + 3, dstb, C.dst, dnode, H_dst, hf.dst_node, "Destination")
    tree_address(c_o + 4, srcb, C.src, snode, H_src, hf.src_node, "Source")
    if mode == SHOWN then
        ti_gen(ti_add(ti, hf.kind, kind))
    elseif REF[hf.kind] ~= false then
        hadd(ti, hf.kind, kind)
    end
    if X.malformed then ti_expert(ti, ei.malformed, C.malformed_msg) end
end

------------------------------------------------------------------------------
-- A variable: its subtree and items (tree_variable).
------------------------------------------------------------------------------
-- A hidden variable's subtree: the item its items go on (the protocol item when nobody references
-- sharedlink.var; no tree: the protocol item).
local function var_item()
    local ti = c_ti
    if REF[H_var] == false then return ti end
    return hadd(ti, H_var) or ti
end

-- Its T field (field tf; shown: the type or an expert when it is not a number), hidden: its type.
local function var_type(vt, v, tf, vtype)
    if c_shown then
        local tvb, o = c_tvb, c_o
        if vtype then
            ti_add(vt, H_ftype, tvb(o + FS[tf] + 1, FE[tf] - FS[tf]), vtype)
        else
            vt:add(tvb(o + FS[tf], FE[tf] - FS[tf] + 1), "Type (T): " .. tostring(VT[v] or ""))
                :add_proto_expert_info(ei.var_badvalue, "Type is not a number")
        end
    elseif vtype then
        if REF[H_ftype] ~= false then hadd(vt, H_ftype, vtype) end
    else
        ti_expert(vt, ei.var_badvalue, "Type is not a number")
    end
end

-- Its name: the subtree's label, its field kept for filters, hidden (and a reply's R); an expert
-- for a positional value past a list learnt from a declaration (docs/fields-sharedlink.md, "Names
-- from an a-priori list": past a user's or the a-priori list a slot is #i with no warning).
local function var_name(vt, v, name)
    local shown = c_shown
    local list = c_list
    if not VN[v] and not list[VI[v] + 1] and list.decl then
        ti_expert(vt, ei.var_unknown)   -- (its slot: sharedlink.var.index)
    end
    do
        local r
        if shown then
            local tvb, o = c_tvb, c_o
            if VN[v] then
                local qf = VQf[v]
                r = tvb(o + FS[qf] + 1, FE[qf] - FS[qf])
                if VR[v] then ti_add(vt, hf.response, r, name) end
            else
                r = tvb(o + FS[VDf[v]], 1)
            end
            ti_hide(ti_add(vt, H_var_name, r, name))
            return
        end
        if VR[v] and VN[v] and REF[hf.response] ~= false then hadd(vt, hf.response, name) end
        if REF[H_var_name] ~= false then hadd(vt, H_var_name, name) end
    end
end

-- A value's typed field (double, long, string; shown: hidden, at range r) or its var.badvalue.
-- known: the value is a plain decimal already (a named layout's pattern matched it), so a hidden
-- tree nobody asks for doubles skips tonumber; dbl: the value as a double when value_items made
-- it already (false: not a double), nil when not (speed trick, measured: tonumber is ~1,150
-- instructions).
local function typed_value(vt, r, vtype, text, known, dbl)
    local field, v
    if vtype == 2 then
        field = H_var_double
        if known and REF[field] == false then return end
        if dbl == nil then v = tonumber(text) else v = dbl end
        if not v then ti_expert(vt, ei.var_badvalue, "Not a double") end   -- (the text: sharedlink.var.value)
    elseif vtype == 0 then
        field, v = hf.var_long, parse_long(text)
        if not v then ti_expert(vt, ei.var_badvalue, "Not a long (int64)") end
    elseif vtype == 4 then
        field, v = hf.var_string, text
    end
    if not v then return end
    if c_shown then
        ti_hide(ti_add(vt, field, r, v))
    elseif REF[field] ~= false then
        hadd(vt, field, v)
    end
end

-- A generated item of field with value x under vt (shown), at range r when r is not nil.
local function gen_item(vt, field, r, x)
    local it
    if r then it = ti_add(vt, field, r, x) else it = ti_add(vt, field, x) end
    ti_gen(it)
    return it
end

-- A variable's value items: sharedlink.var.value (shown: at range r, or generated when gen, a
-- carried value with no bytes of its own), for a value in the frame, carried forward, or of a
-- named variable the frame left out, then (vtype: a value in the frame of that type) its typed
-- field.  The one place a variable's value becomes items: fields per variable (issue 29) go here.
-- name: false for a value that is not its direction's (a reply's: it gets no value field).
local function value_items(vt, name, value, r, gen, vtype, known)
    local shown = c_shown
    if shown then
        if gen then gen_item(vt, H_var_value, r, value) else ti_add(vt, H_var_value, r, value) end
    elseif REF[H_var_value] ~= false then
        hadd(vt, H_var_value, value)
    end
    -- sharedlink.value.<name> (docs/fields-sharedlink.md, "Filtering by variable"): typed as its
    -- field; a value that does not read as that type is left out.  Hidden: the Value line shows it.
    local vf = name and VALUE[name]
    local dbl = nil   -- the value as a double, once made (false: not a double)
    if vf then
        local field = vf.field
        if shown or REF[field] ~= false then
            local ftype, x = vf.vtype, value
            if ftype == 2 then x = tonumber(value); dbl = x or false
            elseif ftype == 0 then x = parse_long(value) end
            if x ~= nil then
                if shown then
                    ti_hide(gen and gen_item(vt, field, r, x) or ti_add(vt, field, r, x))
                else
                    hadd(vt, field, x)
                end
            end
        end
    end
    if shown and dbl and vtype == 2 then   -- (typed_value's most common case, inline: speed trick, measured)
        ti_hide(ti_add(vt, H_var_double, r, dbl))
    elseif vtype then
        typed_value(vt, r, vtype, value, known, dbl)
    end
end

-- A carried value's items: its value and frame when known (cv, cf: false when not), at range r0
-- (shown), the subtree's text set to label ... .
local function carried_items(vt, name, label, cv, cf, r0)
    local shown = c_shown
    if cv then value_items(vt, name, cv, r0, true) end
    if shown then
        ti_gen(r0 and ti_add(vt, H_var_carried, r0, true) or ti_add(vt, H_var_carried, true))
    elseif REF[H_var_carried] ~= false then
        hadd(vt, H_var_carried, true)
    end
    if cf then
        if shown then
            ti_gen(r0 and ti_add(vt, H_var_carried_from, r0, cf) or ti_add(vt, H_var_carried_from, cf))
            ti_text(vt, label .. " = " .. tostring(cv) .. " (carried from frame " .. cf .. ")")
        elseif REF[H_var_carried_from] ~= false then
            hadd(vt, H_var_carried_from, cf)
        end
    elseif shown then
        ti_text(vt, label .. " = ? (carried, no earlier value)")
    end
end

-- A reply's link to its query (or the expert of a reply without one).
local function var_reply(vt, name)
    local resp_to, unmatched = C.resp_to, C.unmatched
    if resp_to and resp_to[name] then
        if c_shown then
            ti_gen(ti_add(vt, hf.response_to, resp_to[name]))
            ti_gen(ti_add(vt, hf.response_time, U.nstime_of(C.rts[name])))
        else
            hitem(vt, hf.response_to, resp_to[name])
            if REF[hf.response_time] ~= false then hadd(vt, hf.response_time, U.nstime_of(C.rts[name])) end
        end
    elseif unmatched and unmatched[name] then
        ti_expert(vt, ei.unanswered)
    end
end

-- A variable's value (its D), or what a declaration or a reply without value shows.
local function var_value(vt, v, name, vtype)
    local shown = c_shown
    local val, label = VV[v], shown and (name or slot_name(c_list, VI[v]))
    if not val then
        if shown then ti_text(vt, label .. (VR[v] and " (reply without value)" or " (declared)")) end
        local resp_in = C.resp_in
        if resp_in and resp_in[name] then
            if shown then ti_gen(ti_add(vt, hf.response_in, resp_in[name]))
            else hitem(vt, hf.response_in, resp_in[name]) end
        end
        return
    end
    if val ~= "" or VN[v] then
        local r = nil
        if shown then local df = VDf[v]; r = c_tvb(c_o + FS[df] + 1, FE[df] - FS[df]) end
        value_items(vt, not VR[v] and name, val, r, false, vtype, c_tv ~= nil)
        if shown then ti_text(vt, label .. " = " .. val) end
    else
        -- an empty positional D: the value carried forward (the frame's next carried pair)
        local ke, csrc = c_ke, c_csrc
        local cv, cf = false, false
        if csrc then cv, cf = csrc[ke + 1], csrc[ke + 2] end
        c_ke = ke + 2
        carried_items(vt, name, label, cv, cf, shown and c_tvb(c_o + FS[VDf[v]], 1))
    end
    if VR[v] then var_reply(vt, name) end
end

-- Variable v's name, index and type: a positional one's from the list (#i past it), a named one's
-- index its place among the direction's names, a reply's type (without T) from its direction's list.
local function var_naming(v, name, index)
    if not name then
        local list = c_list
        return slot_name(list, index), index, list.t[index + 1]
    end
    if VR[v] then return name, index, M.state.list_type(c_list, name) end
    local d = c_d
    if d then
        local first = d.nfirst[name]
        index = (first and first <= c_num) and d.npos[name] or nil
    end
    return name, index, nil
end

-- Variable v: its subtree (shown: at its first field fs) and every item of it.  A named
-- variable's index is its place among the direction's names; a positional one's name and type
-- come from the list.
-- Shown: the variable's subtree at its first field fs, its T item and (a named variable's, not a
-- reply's) its name item; returns the subtree and the type (vtype: the list's when no T).  Speed
-- trick (measured, -V): the common items made here, no var_type or var_name call.
local function shown_var_head(v, fs, name, vtype)
    local tf, qf, df = VTf[v], VQf[v], VDf[v]
    local vend = df ~= 0 and df or (qf ~= 0 and qf or tf)
    local tvb, o = c_tvb, c_o
    local vt = ti_add(c_ti, H_var, tvb(o + fs, FE[vend] - fs + 1))
    if tf ~= 0 then
        local tv = c_tv
        vtype = tv and tv[v] or valid_type(VT[v])
        if vtype then ti_add(vt, H_ftype, tvb(o + FS[tf] + 1, FE[tf] - FS[tf]), vtype)
        else var_type(vt, v, tf, vtype) end
    elseif VT[v] then   -- a name with no T of its own: the frame's last T (parse's add_var), generated
        vtype = valid_type(VT[v])
        ti_gen(ti_add(vt, H_ftype, vtype))
    end
    if VN[v] and not VR[v] then
        ti_hide(ti_add(vt, H_var_name, tvb(o + FS[qf] + 1, FE[qf] - FS[qf]), name))
    else
        var_name(vt, v, name)
    end
    return vt, vtype
end

-- Hidden (or none): the variable's item (var_item), its T item and its name item; returns the
-- item and the type (vtype: the list's when no T).
local function hidden_var_head(v, name, vtype)
    local vt = var_item()
    -- a T field: its field number where the places are known (the parser may leave a T's number
    -- with VT false: shown as an empty type), else (a layout's frame) its text; a name with no T
    -- of its own and the frame's last T (VT, VTf 0)
    if VT[v] or (c_places and VTf[v] ~= 0) then
        local tv = c_tv
        vtype = tv and tv[v] or valid_type(VT[v])
        var_type(vt, v, VTf[v], vtype)
    end
    var_name(vt, v, name)
    return vt, vtype
end

-- Variable v: its subtree (shown: at its first field fs) and every item of it.  A named
-- variable's index is its place among the direction's names; a positional one's name and type
-- come from the list.
local function tree_variable(v, fs)
    local name, index, vtype = VN[v], VI[v], nil
    if not name or VR[v] then
        name, index, vtype = var_naming(v, name, index)
    elseif c_d then   -- (var_naming's most common case, inline: speed trick, measured)
        local d = c_d
        local first = d.nfirst[name]
        index = (first and first <= c_num) and d.npos[name] or nil
    end
    local vt
    if c_shown then vt, vtype = shown_var_head(v, fs, name, vtype)
    else vt, vtype = hidden_var_head(v, name, vtype) end
    if not VR[v] and index then
        if c_shown then ti_gen(ti_add(vt, H_var_index, index))
        elseif REF[H_var_index] ~= false then hadd(vt, H_var_index, index) end
    end
    var_value(vt, v, name, vtype)
end

------------------------------------------------------------------------------
-- The fields that are not part of a variable.
------------------------------------------------------------------------------
-- An item of field at the text after the letter (shown: range vr), value text; the item or nil.
local function plain_item(parent, field, vr, text)
    if c_shown then return ti_add(parent, field, vr, text) end
    return hitem(parent, field, text)
end

-- An item with no field (shown only: a text at f[fs..fe]) and its expert.
local function text_item(fs, fe, text, expert, etext)
    local ti = c_ti
    if c_shown then ti = ti_add(ti, c_tvb(c_o + fs, fe - fs + 1), text) end
    ti_expert(ti, expert, etext)
end

-- An N, L or T field (letter l, text at f[fs+1..fe]): its number, or an expert when it is none.
local function number_field(l, fs, fe, text, vr)
    if l == U.L_T then
        local t = valid_type(text)
        if t then plain_item(c_ti, H_ftype, vr, t)
        else text_item(fs, fe, "Type (T): " .. text, ei.var_badvalue, "Type is not a number") end
        return
    end
    -- an ordinal is decimal digits only, as the state reads it (parse's state_ordinal: 1e3, +5,
    -- 0x10 and 5.5 are no number there, so none here either; issue 40)
    local n = not string.find(text, "[^0-9]") and tonumber(text)
    if n and n < 4294967296 then
        plain_item(c_ti, l == U.L_N and H_ordinal or hf.inbound_ordinal, vr, floor(n))
    else
        text_item(fs, fe, (l == U.L_N and "Ordinal (N): " or "Inbound ordinal (L): ") .. text,
            ei.var_badvalue, "Ordinal is not a number")
    end
end

-- A field of an unknown letter (or a C that is not the last field).
local function unknown_field(l, fs, fe)
    local ti = c_ti
    local ft
    if c_shown then
        local tvb, o = c_tvb, c_o
        ft = ti_add(ti, hf.field_letter, tvb(o + fs, 1), LETTER[l])
        ti_add(ft, hf.field_text, tvb(o + fs, fe - fs + 1), s_sub(c_f, fs, fe))
    else
        ft = hitem(ti, hf.field_letter, LETTER[l])
        hitem(ti, hf.field_text, s_sub(c_f, fs, fe))
    end
    if l == U.L_C then
        ti_expert(ft or ti, ei.field_unknown, "Checksum field C that is not the last field")
    else
        ti_expert(ft or ti, ei.field_unknown)   -- (the letter: sharedlink.field.letter)
    end
end

-- the plain fields by letter: their field (E: the command, whose D arguments follow it)
local PLAIN = { [U.L_R] = hf.response, [U.L_E] = hf.command, [U.L_M] = hf.mode, [U.L_P] = hf.ping, [U.L_G] = hf.pong }

-- A field that is not part of a variable (letter l, f[fs..fe]).
local function tree_plain_field(l, fs, fe)
    local ti, resp_in, shown = c_ti, C.resp_in, c_shown
    local text = (l ~= false) and s_sub(c_f, fs + 1, fe) or ""
    local vr = shown and c_tvb(c_o + fs + 1, fe - fs)     -- the text after the letter
    if l == false then
        if shown then ti = ti_add(ti, U.zrange(c_tvb, c_o + fs), "Empty field") end
        ti_expert(ti, ei.field_empty)
    elseif l == U.L_N or l == U.L_L or l == U.L_T then
        number_field(l, fs, fe, text, vr)
    elseif l == U.L_Q then
        local qt = plain_item(ti, hf.query, vr, text)
        if resp_in and resp_in[text] then
            if shown then ti_gen(ti_add(qt, hf.response_in, resp_in[text]))
            else hitem(ti, hf.response_in, resp_in[text]) end
        end
    elseif PLAIN[l] then
        local item = plain_item(ti, PLAIN[l], vr, text)
        if l == U.L_E then C.cmd_item = item or ti end
    elseif l == U.L_D then
        plain_item(C.cmd_item or ti, hf.command_arg, vr, text)
    else
        unknown_field(l, fs, fe)
    end
end

-- The fields in order; a variable is rendered at its first field.  A frame the layout cache
-- parsed has its fields' places only for a shown tree (parse): for the others its fields are
-- N, then its variables (the layout's order), then C (the trailer).
--
-- Speed device (measured, -Y on a frame's own field): a hidden tree (or none) leaves out the
-- variables of a layout's frame when they carry no expert info and every field their items would
-- have is known to be unreferenced (a field made per variable value, issue 29, is checked here too).
local layout_vars_unseen, carried_unseen
do
local TYPED = { [0] = hf.var_long, [2] = H_var_double, [4] = hf.var_string }

-- Whether nobody references the value field (sharedlink.value.<name>) of a variable of the
-- frame (n: F.nv) or, with miss, of a named variable it left out (name, value, frame, ...; n entries).
function C.value_fields_unseen(n, miss)
    local list = c_list
    local step = miss and 3 or 1
    for k = 1, n, step do
        local name
        if miss then name = miss[k] else name = VN[k] or list[VI[k] + 1] end
        local vf = name and VALUE[name]
        if vf and REF[vf.field] ~= false then return false end
    end
    return true
end

-- Whether nobody references the value fields of the frame's variables (C.value_fields_unseen).
-- A named layout's (sharedlink.value.<name> of its names that have one) are kept by the layout
-- (VF_OF, weak: the layout cache drops layouts) and asked in one loop the first time its frame
-- needs them since LEARNT last forgot (vfs.gen: ASKED.gen), a call each, not the metamethod's
-- (speed trick, measured: the GUI's rows); then read from LEARNT.
C.vars_value_fields_unseen = (function()
    local VF_OF = setmetatable({}, { __mode = "k" })
    local function named_vfields(named)
        local vfs = { gen = -1 }
        for v = 1, F.nv do
            local vf = VALUE[VN[v]]
            if vf then vfs[#vfs + 1] = vf.field end
        end
        VF_OF[named] = vfs
        return vfs
    end
    local function ask_all(vfs, n)
        local ask, root, learnt, asked, na = ti_ref, ref_root, LEARNT, ASKED, n_asked
        local unseen = true
        for k = 1, n do
            local field = vfs[k]
            local r = ask(root, field)
            learnt[field] = r
            na = na + 1
            asked[na] = field
            if r then unseen = false end
        end
        n_asked = na
        return unseen
    end
    return function()
        local named = F.named
        if not named then return C.value_fields_unseen(F.nv) end
        local vfs = VF_OF[named] or named_vfields(named)
        local n, gen = #vfs, ASKED.gen
        if n == 0 then return true end
        if vfs.gen ~= gen then
            vfs.gen = gen
            return ask_all(vfs, n)
        end
        local learnt = LEARNT
        for k = 1, n do
            if learnt[vfs[k]] then return false end
        end
        return true
    end
end)()

function layout_vars_unseen()
    if REF ~= NO_REF then
        if not C.vars_value_fields_unseen() then return false end
        if REF[H_var] ~= false or REF[H_var_name] ~= false or REF[H_var_index] ~= false
            or REF[H_var_value] ~= false or (c_tv and REF[H_ftype] ~= false) then
            return false
        end
        if F.n_empty_d > 0 and (REF[H_var_carried] ~= false or REF[H_var_carried_from] ~= false) then return false end
        local tv, lt = c_tv, c_list.t
        if tv or lt then
            for v = 1, F.nv do
                local t = tv and tv[v] or (not tv and lt[VI[v] + 1])
                if t and REF[TYPED[t]] ~= false then return false end
            end
        end
    end
    return not values_have_experts(C.kind, c_list)
end

-- Whether a hidden tree (or none) may leave out the named variables a frame left out: nobody
-- references a field of theirs (speed device, as layout_vars_unseen).
function carried_unseen(miss, miss_len)
    return REF == NO_REF or (REF[H_var] == false and REF[H_var_name] == false and REF[H_var_index] == false
        and REF[H_var_value] == false and REF[H_var_carried] == false and REF[H_var_carried_from] == false
        and C.value_fields_unseen(miss_len, miss))
end
end

local function layout_fields()
    if REF[H_ordinal] ~= false then
        local n = F.n_ord   -- 0 also for an N past what to_ordinal keeps
        if n == 0 and F.n_text ~= "0" then n = floor(tonumber(F.n_text)) end
        hadd(c_ti, H_ordinal, n)
    end
    if layout_vars_unseen() then return end
    for v = 1, F.nv do tree_variable(v) end
end

-- A layout's frame, shown (its places from parse): N, its variables in order (a variable's first
-- field its T, else its D), C; no walk to find which field starts which variable (speed trick,
-- measured: -V).
local function shown_layout_fields()
    local ns, ne = FS[1], FE[1]
    local n = F.n_ord   -- the layout's N: digits only, its number unless 0 (0 also for an N past
    if n ~= 0 or F.n_text == "0" then   -- what to_ordinal keeps): no tonumber, floor (speed trick, measured)
        ti_add(c_ti, H_ordinal, c_tvb(c_o + ns + 1, ne - ns), n)
    else
        number_field(U.L_N, ns, ne, F.n_text, c_tvb(c_o + ns + 1, ne - ns))
    end
    for v = 1, F.nv do
        local first = VTf[v]
        if first == 0 then first = VDf[v] end
        tree_variable(v, FS[first])
    end
end

local function tree_fields()
    if not c_places then return layout_fields() end
    if F.layout then return shown_layout_fields() end
    local kind, cpos = C.kind, F.cpos
    for i = 1, F.nf do FV[i] = 0; FC[i] = false end
    for v = 1, F.nv do
        if VV[v] or kind == "declaration" or VR[v] then
            local first = VTf[v] ~= 0 and VTf[v] or (VQf[v] ~= 0 and VQf[v] or VDf[v])
            FV[first] = v
            if VQf[v] ~= 0 and VQf[v] ~= first then FC[VQf[v]] = true end
            if VDf[v] ~= 0 and VDf[v] ~= first then FC[VDf[v]] = true end
        end
    end
    for i = 1, F.nf do
        local fs = FS[i]
        local v = FV[i]
        if v ~= 0 then
            tree_variable(v, fs)
        elseif not FC[i] and fs ~= cpos then
            tree_plain_field(FL[i], fs, FE[i])
        end
    end
end

-- A list request's link to the declaration that answers it, and back (docs/fields-sharedlink.md,
-- "Replies": L? is answered by an N declaration, N? by an L one).
function C.request_link(rec)
    local ti, shown = c_ti, c_shown
    if rec.req_in then
        if shown then ti_gen(ti_add(ti, hf.response_in, rec.req_in))
        else hitem(ti, hf.response_in, rec.req_in) end
    end
    if rec.req_to then
        if shown then
            ti_gen(ti_add(ti, hf.response_to, rec.req_to))
            ti_gen(ti_add(ti, hf.response_time, U.nstime_of(rec.req_rt)))
        else
            hitem(ti, hf.response_to, rec.req_to)
            hitem(ti, hf.response_time, U.nstime_of(rec.req_rt))
        end
    end
end


-- Named variables this frame left out (carried forward): name, value, frame in miss.
local function tree_carried_names()
    local rec, nm, d = C.rec, C.nm, c_d
    local miss = rec and rec.miss
    local miss_len = miss and #miss or 0
    if not miss and nm > 0 then miss, miss_len = MISS, nm end    -- packed on this pass
    if not miss then return end
    local shown, ti = c_shown, c_ti
    if not shown and carried_unseen(miss, miss_len) then return end
    local zr = shown and U.zrange(c_tvb, c_o + C.bodyend)
    for k = 1, miss_len, 3 do
        local name, cv, cf = miss[k], miss[k + 1], miss[k + 2]
        local index = d and d.npos[name]
        local vt
        if shown then
            vt = ti_add(ti, H_var, zr)
            ti_hide(ti_add(vt, H_var_name, name))
            if index then ti_gen(ti_add(vt, H_var_index, index)) end
        else
            vt = var_item()
            if REF[H_var_name] ~= false then hadd(vt, H_var_name, name) end
            if index and REF[H_var_index] ~= false then hadd(vt, H_var_index, index) end
        end
        carried_items(vt, name, name, cv, cf, nil)
        if shown then ti_gen(vt) end
    end
end

------------------------------------------------------------------------------
-- The trailer: limits, sync, checksum, line end.
------------------------------------------------------------------------------
-- The checksum field (at cpos, text ctext), its verdict and experts.
local CHECKSUM_OK = {}   -- value -> "Checksum: 0x.. [correct]"
local function shown_checksum(cpos, ctext)
    local ti, val, cs_status = c_ti, C.cs_val, C.cs_status
    local cr = c_tvb(c_o + cpos, #ctext + 1)
    local byte_val = val and val <= 255
    local ct
    if byte_val and cfg.validate and cs_status == 1 then
        -- the label with " [correct]", one call (speed trick, measured: -V)
        local label = CHECKSUM_OK[val]
        if not label then
            label = string.format("Checksum: 0x%02x [correct]", val)
            CHECKSUM_OK[val] = label
        end
        ct = ti_add(ti, H_checksum, cr, val, label)
    elseif byte_val then
        ct = ti_add(ti, H_checksum, cr, val)
    else
        ct = ti_add(ti, hf.checksum_text, cr, ctext)
    end
    if X.checksum_format then   -- (the text as written in a field of its own, issue 41)
        if byte_val then ti_add(ct, hf.checksum_text, cr, ctext) end
        ti_expert(ct, ei.checksum_format)
    end
    if not cfg.validate then
        ti_gen(ti_add(ct, H_checksum_status, cr, 2))
        return
    end
    local cs_calc = C.cs_calc
    ti_gen(ti_add(ct, H_checksum_calc, cr, cs_calc))
    if cs_status == 1 then
        ti_gen(ti_add(ct, H_checksum_status, cr, 1))
        if not byte_val then ti_append(ct, " [correct]") end
    else
        ti_gen(ti_add(ct, H_checksum_status, cr, 0))
        ti_append(ct, string.format(" [incorrect, should be 0x%02x]", cs_calc))
        -- one summary a problem (issue 41): the values are sharedlink.checksum and .calculated
        ti_expert(ct, ei.checksum_bad)
    end
end

-- The same items in a hidden tree (or none), on the protocol item.
local function hidden_checksum(ctext)
    local ti, val, cs_status = c_ti, C.cs_val, C.cs_status
    local ct
    if val and val <= 255 then
        if REF[H_checksum] ~= false then ct = hadd(ti, H_checksum, val) end
    elseif REF[hf.checksum_text] ~= false then
        ct = hadd(ti, hf.checksum_text, ctext)
    end
    if X.checksum_format then
        if val and val <= 255 then hitem(ti, hf.checksum_text, ctext) end
        ti_expert(ct or ti, ei.checksum_format)
    end
    if not cfg.validate then
        if REF[H_checksum_status] ~= false then hadd(ti, H_checksum_status, 2) end
        return
    end
    local cs_calc = C.cs_calc
    if REF[H_checksum_calc] ~= false then hadd(ti, H_checksum_calc, cs_calc) end
    if REF[H_checksum_status] ~= false then hadd(ti, H_checksum_status, cs_status) end
    if X.checksum_bad then ti_expert(ct or ti, ei.checksum_bad) end
end

local function tree_trailer()
    local ti, rec, shown = c_ti, C.rec, c_shown
    if X.limit then ti_expert(ti, ei.limit, F.limit) end
    if X.rec_limit then ti_expert(ti, ei.limit, rec.limit) end
    if X.sync_late then
        -- one summary a problem (issue 41): the time since the last full frame in sharedlink.sync.gap
        local gap = U.nstime_of(rec.late)
        if shown then
            ti_gen(ti_add(ti, hf.sync_is_late, true))
            ti_gen(ti_add(ti, hf.sync_gap, gap))
        else
            hitem(ti, hf.sync_is_late, true)
            hitem(ti, hf.sync_gap, gap)
        end
        ti_expert(ti, ei.sync_late)
    end
    if F.cpos then
        if shown then shown_checksum(F.cpos, F.ctext) else hidden_checksum(F.ctext) end
    else
        if shown then ti_gen(ti_add(ti, H_checksum_status, 2))
        else hitem(ti, H_checksum_status, 2) end
        if X.checksum_missing then ti_expert(ti, ei.checksum_missing) end
    end
    if X.crlf_missing then ti_expert(ti, ei.crlf_missing) end   -- (line terminator)
end

------------------------------------------------------------------------------
-- The builder.
------------------------------------------------------------------------------
-- A hidden tree's calm frame (fr.calm: no expert), every ASK_FIRST field unreferenced
-- (first_unseen): whether its tree is the protocol item alone, as the full build would leave it: a
-- layout's frame (its N, head and variable items are ASK_FIRST's), no carried names, a checksum
-- of one byte, its variables unseen (layout_vars_unseen, which asks their other fields; C's
-- functions, not locals: the main chunk's 150).  The GUI's
-- packet list rows with the coloring rules (experts only) take this way (speed trick, measured).
function C.tree_dir(fr)
    local list, d = M.state.later_tree_dir()
    if list then fr.list, fr.d = list, d end
end
function C.calm_unseen(fr)
    local val = fr.cs_val
    if not F.layout or fr.nm ~= 0 or (F.cpos and not (val and val <= 255)) then return false end
    if fr.visited and not F.named then C.tree_dir(fr) end
    c_tv, c_list, C.kind = F.named and F.named.TV, fr.list, fr.kind
    return layout_vars_unseen()
end

-- Start frame fr's tree: the fields' answers (REF, ref_start); true when the tree is done there (a
-- hidden calm frame nobody references a field of: the protocol item alone, calm_unseen).  Past
-- it (and for a layout of positional values there), a later pass's frame gets its direction and
-- list if the state left them to the tree (state.lua later_tree_dir: found only where needed).
local function tree_start(mode, tree, tvb, fr)
    if mode == NONE then REF = NO_REF; return false end
    REF = LEARNT
    ref_start(tree, tvb, mode == HIDDEN, not fr.visited)
    if first_unseen and mode == HIDDEN and fr.calm and C.calm_unseen(fr) then
        ti_add(tree, sl, tvb(fr.a - 1, fr.e - fr.a + 1))
        return true
    end
    if fr.visited then C.tree_dir(fr) end
    return false
end

-- The tree of frame fr (the frame record: at f[1..fl], bodyend its content's last index, starting
-- at s[a] and ending with its line end at s[e], as parsed: the field and variable arrays, cpos,
-- ctext; a shown tree needs the fields' places, which parse fills for it; with its kind, state
-- and checksum verdict).  mode: SHOWN, HIDDEN or NONE (then tree: the tree Wireshark gave, which
-- keeps no item); fr.visited: pinfo.visited (what a hidden tree asked of Wireshark is kept over a
-- first pass only).  Called by dissect_frame; what the parts share goes in the c_ upvalues.
local function tree_frame(mode, tree, tvb, fr)
    if not ti_bound then bind_ti() end
    frame_experts(fr)
    if tree_start(mode, tree, tvb, fr) then return end
    c_shown = mode == SHOWN
    local a, dstb, srcb, rec = fr.a, fr.dstb, fr.srcb, fr.rec
    -- tvb offset of f[i] is o + i
    C.mode, C.tree, c_tvb, c_o, c_f, C.a, C.e = mode, tree, tvb, a - 2, fr.f, a, fr.e
    c_num, C.visited, C.kind, C.dstb, C.srcb = fr.num, fr.visited, fr.kind, dstb, srcb
    C.dst, C.src = dstb and LETTER[dstb] or "?", srcb and LETTER[srcb] or "?"
    C.malformed_msg, C.bodyend = fr.malformed, fr.bodyend
    c_list, c_d, C.rec, C.nm = fr.list, fr.d, rec, fr.nm
    C.cs_val, C.cs_calc, C.cs_status = fr.cs_val, fr.cs_calc, fr.cs_status
    C.resp_in, C.resp_to = rec and rec.resp_in, rec and rec.resp_to
    C.rts, C.unmatched = rec and rec.rt, rec and rec.unmatched
    -- the carried values of empty D fields (value, frame, ...), ke: how many used so far
    c_csrc, c_ke = rec or (fr.ne > 0 and CARRY), 0
    C.cmd_item = nil   -- the E field's item
    c_tv = F.named and F.named.TV     -- a named layout's types (valid, doubles plain decimals)
    c_places = mode == SHOWN or not F.layout   -- the fields' places (FL, FS, FE, VTf...) are known
    tree_head()
    tree_fields()
    if rec and (rec.req_in or rec.req_to) then C.request_link(rec) end
    tree_carried_names()
    tree_trailer()
end

local T = { tree_frame = tree_frame }
return T
