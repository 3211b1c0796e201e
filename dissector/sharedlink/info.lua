-- SharedLink dissector module: info, the Info column: the pieces of a packet's frames, cut at INFO_MAX.
-- Loaded by sharedlink.lua (load_module); Wireshark also runs every .lua file of a plugin folder's
-- subfolders as a plugin of its own: this file then does nothing.

local token, M = ...
if type(token) ~= "table" or token.sharedlink_module ~= true then return end

local U, s_sub, s_find, s_gsub = M.util, string.sub, string.find, string.gsub
local t_concat, ARROW, ELLIPSIS, INFO_MAX = table.concat, U.ARROW, U.ELLIPSIS, U.INFO_MAX
local F = M.parse.F   -- the frame record (parse.lua)
local CTRL, VN, VV, VI, LETTER, slot_name = U.CTRL, F.VN, F.VV, F.VI, U.LETTER, U.slot_name
local CARRIED_TAIL = U.CARRIED_TAIL

local MARKS = M.parse.MARKS
local FAST_MARK = MARKS.fast   -- (SHAREDLINK_FAST_MARK=1: a switch read once, at load)

------------------------------------------------------------------------------
-- Info column pieces (reused)
------------------------------------------------------------------------------
local INFO = {}
local ninfo, info_len, info_full = 0, 0, false
local info_clean = true     -- every piece came from the named fast path
-- single: the packet's one piece so far, when info_layout made it (speed trick, measured: I.finish
-- writes it with no test of the pieces; spill puts it in INFO when another piece follows)
local single = nil
local frames_in_info, frames_dropped = 0, 0

local function info_add(str)
    if info_full then return end
    local l = #str
    ninfo = ninfo + 1
    if info_len + l > INFO_MAX then
        INFO[ninfo] = ELLIPSIS
        info_full = true
        return
    end
    INFO[ninfo] = str
    info_len = info_len + l
end

-- The values (name=value), and how many the frame carried.
local function info_values(list, miss_n)
    for v = 1, F.nv do
        if info_full then break end
        local val = VV[v]
        if val and (val ~= "" or VN[v]) then
            info_add(" " .. (VN[v] or slot_name(list, VI[v])) .. "=" .. val)
        end
    end
    local nc = F.n_empty_d + miss_n
    if nc > 0 then info_add(" (+" .. nc .. " carried)") end
end

-- The names a query or declaration asks for or declares.
local function info_names()
    for v = 1, F.nv do
        if VN[v] then info_add(" " .. VN[v]) end
    end
end

-- The frame's piece, piece by piece (F: the frame record; its address bytes dstb, srcb, nil when
-- cut short: "?").
local function info_pieces(fr)
    local kind, rec = fr.kind, fr.rec
    info_add(LETTER[fr.srcb] .. ARROW .. LETTER[fr.dstb] .. " " .. kind)
    if fr.is_data or kind == "reply" or kind == "malformed" then
        info_values(fr.list, fr.miss_n)
    elseif kind == "query" then
        info_names()
    elseif kind == "declaration" then
        info_add(fr.l_ord and (" L" .. fr.l_ord) or (" N" .. (fr.n_ord or 0)))
        info_names()
    elseif kind == "command" and fr.cmd_start then
        local cpos = fr.cpos
        local cmd = s_gsub(s_sub(fr.f, fr.cmd_start, cpos and cpos - 2 or fr.bodyend), "|D?", " ")
        info_add(" " .. cmd)
    end
    if rec and rec.late then info_add(" [sync late]") end
end

-- A named layout's pieces (p: what goes before each value) and its values (VV) joined, with tail,
-- by the number of values (a layout has at most 8): one concatenation (speed trick, measured: a
-- loop into table.concat cost 40 Lua VM instructions a frame more, about 4 % of the summary pass).
local JOIN = {
    [0] = function(p, tail) return p[1] .. tail end,   -- (a layout of no value: its head)
    function(p, tail) return p[1] .. VV[1] .. tail end,
    function(p, tail) return p[1] .. VV[1] .. p[2] .. VV[2] .. tail end,
    function(p, tail) return p[1] .. VV[1] .. p[2] .. VV[2] .. p[3] .. VV[3] .. tail end,
    function(p, tail) return p[1] .. VV[1] .. p[2] .. VV[2] .. p[3] .. VV[3] .. p[4] .. VV[4] .. tail end,
    function(p, tail)
        return p[1] .. VV[1] .. p[2] .. VV[2] .. p[3] .. VV[3] .. p[4] .. VV[4] ..
            p[5] .. VV[5] .. tail
    end,
    function(p, tail)
        return p[1] .. VV[1] .. p[2] .. VV[2] .. p[3] .. VV[3] .. p[4] .. VV[4] ..
            p[5] .. VV[5] .. p[6] .. VV[6] .. tail
    end,
    function(p, tail)
        return p[1] .. VV[1] .. p[2] .. VV[2] .. p[3] .. VV[3] .. p[4] .. VV[4] ..
            p[5] .. VV[5] .. p[6] .. VV[6] .. p[7] .. VV[7] .. tail
    end,
    function(p, tail)
        return p[1] .. VV[1] .. p[2] .. VV[2] .. p[3] .. VV[3] .. p[4] .. VV[4] ..
            p[5] .. VV[5] .. p[6] .. VV[6] .. p[7] .. VV[7] .. p[8] .. VV[8] .. tail
    end,
}

-- The Info piece of a full or delta frame of a named layout or one of no value (F.layout with
-- pieces), as info_pieces makes it, for a full frame that carries nothing or a delta, its tail
-- " (+n carried)" after the values, with no late sync record, when it fits INFO_MAX (else nil):
-- the layout's pieces (parse's named_info, made once a layout: the arrow, the kind and each
-- " name=") and the values.
local function layout_piece(kind, rec, miss_n)
    local named = F.layout
    if not (named and named.pieces) or (rec and rec.late) then return nil end
    local vlen = F.vlen
    if kind == "full" then
        if miss_n ~= 0 or vlen > named.info_room then return nil end
        return JOIN[named.n](named.pieces, "")
    elseif kind ~= "delta" then
        return nil
    end
    local tail = ""
    if miss_n > 0 then tail = CARRIED_TAIL[miss_n] or (" (+" .. miss_n .. " carried)") end
    if vlen + #tail > named.dinfo_room then return nil end
    return JOIN[named.n](named.dpieces, tail)
end

-- Info column: this frame's piece, a full or delta frame of a named layout alone in its packet so
-- far: layout_piece's, when it fits INFO_MAX.  Returns whether it made one (else the entry calls
-- info_frame).  The entry writes the piece of a packet's only frame itself (I.first: when more
-- frames follow).
local function info_layout(kind, rec, miss_n)
    if frames_in_info ~= 0 then return false end
    local piece = layout_piece(kind, rec, miss_n)
    if not piece then return false end
    frames_in_info, single = 1, piece
    return true
end

-- The single piece info_layout made goes into INFO, before another piece joins it.
local function spill()
    ninfo, info_len, INFO[1], single = 1, #single, single, nil
end

-- Info column: this frame's piece, piece by piece (what info_layout does not make; F: the frame
-- record, with the state's answers).
local function info_frame(fr)
    if single then spill() end
    if frames_in_info > 0 then
        if info_full then frames_dropped = frames_dropped + 1 else info_add(" ; ") end
    end
    frames_in_info = frames_in_info + 1
    info_clean = false
    if not info_full then info_pieces(fr) end
end

-- No pieces yet: at the start of a capture, after each packet's Info (I.finish), and before a
-- packet whose previous one did not reach I.finish (a Lua error; see the entry's dissect).
local I = {}
function I.begin()
    ninfo, info_len, info_full, frames_in_info, frames_dropped = 0, 0, false, 0, 0
    info_clean, single = true, nil
end

-- The piece of the packet's first frame, which the entry got from I.first_piece, when more frames
-- follow (as info_layout's).
function I.first(piece)
    frames_in_info, single = 1, piece
end

-- Noise of len bytes between frames, as a piece of its own.
function I.noise(len)
    if single then spill() end
    if info_full then
        frames_dropped = frames_dropped + 1
    else
        if frames_in_info > 0 then info_add(" ; ") end
        info_add("noise (" .. len .. " bytes)")
        frames_in_info = frames_in_info + 1
    end
end

-- The packet's Info, into the column; then no pieces (as I.begin: speed trick, measured, no call
-- a packet to start one).
function I.finish(cols)
    if single then
        -- one frame's piece by info_layout (the commonest packet): nothing dropped, no control character
        cols.info = single
        single, frames_in_info = nil, 0
        return
    end
    if frames_dropped > 0 then
        ninfo = ninfo + 1
        INFO[ninfo] = " (+" .. frames_dropped .. " more)"
    end
    if ninfo > 0 then
        local info = (ninfo == 1) and INFO[1] or t_concat(INFO, "", 1, ninfo)
        -- control characters from a damaged frame must not break the column (the
        -- fast path's text cannot hold any: its patterns exclude them)
        if not info_clean and s_find(info, CTRL) then info = s_gsub(info, CTRL, "?") end
        cols.info = info
    end
    ninfo, info_len, info_full, frames_in_info, frames_dropped = 0, 0, false, 0, 0
    info_clean = true
end

-- SHAREDLINK_FAST_MARK=1: the Info of a packet the layout cache parsed starts "[fast] " (a switch
-- read once, at load: I.finish is wrapped then, no test a packet otherwise).
if FAST_MARK then
    local finish = I.finish
    function I.finish(cols)
        if MARKS.fast_hit then
            if single then
                single, MARKS.fast_hit = "[fast] " .. single, false
            elseif ninfo > 0 then
                INFO[1], MARKS.fast_hit = "[fast] " .. INFO[1], false
            end
        end
        finish(cols)
    end
end

-- The Info piece of the frame a payload starts with (layout_piece's; off with SHAREDLINK_FAST_MARK,
-- whose mark I.finish puts): the packet's Info when no other frame follows (the entry writes it).
I.first_piece = layout_piece
if FAST_MARK then I.first_piece = function() return nil end end

I.info_frame, I.info_layout = info_frame, info_layout
return I
