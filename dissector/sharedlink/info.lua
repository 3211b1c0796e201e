-- SharedLink dissector module: info, the Info column: the pieces of a packet's frames, cut at INFO_MAX.
-- Loaded by sharedlink.lua (load_module); Wireshark also runs every .lua file of a plugin folder's
-- subfolders as a plugin of its own: this file then does nothing.

local token, M = ...
if type(token) ~= "table" or token.sharedlink_module ~= true then return end

local U, s_sub, s_find, s_gsub = M.util, string.sub, string.find, string.gsub
local t_concat, ARROW, ELLIPSIS, INFO_MAX = table.concat, U.ARROW, U.ELLIPSIS, U.INFO_MAX
local CTRL, VN, VV, VI, LETTER = U.CTRL, M.parse.P.VN, M.parse.P.VV, M.parse.P.VI, U.LETTER

local P = M.parse.P
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
    for v = 1, P.nv do
        if info_full then break end
        local val = VV[v]
        if val and (val ~= "" or VN[v]) then
            local name = VN[v]
            if not name then name = list[VI[v] + 1] or ("#" .. VI[v]) end
            info_add(" " .. name .. "=" .. val)
        end
    end
    local nc = P.n_empty_d + miss_n
    if nc > 0 then info_add(" (+" .. nc .. " carried)") end
end

-- The names a query or declaration asks for or declares.
local function info_names()
    for v = 1, P.nv do
        if VN[v] then info_add(" " .. VN[v]) end
    end
end

-- The frame's piece, piece by piece (dstb, srcb: its address bytes; "?": cut short).
local function info_pieces(f, bodyend, kind, is_data, rec, list, dstb, srcb, miss_n)
    info_add(LETTER[srcb] .. ARROW .. LETTER[dstb] .. " " .. kind)
    if is_data or kind == "reply" or kind == "malformed" then
        info_values(list, miss_n)
    elseif kind == "query" then
        info_names()
    elseif kind == "declaration" then
        info_add(P.l_ord and (" L" .. P.l_ord) or (" N" .. (P.n_ord or 0)))
        info_names()
    elseif kind == "command" and P.cmd_start then
        local cpos = P.cpos
        local cmd = s_gsub(s_sub(f, P.cmd_start, cpos and cpos - 2 or bodyend), "|D?", " ")
        info_add(" " .. cmd)
    end
    if rec and rec.late then info_add(" [sync late]") end
end

-- Info column: this frame's piece, a full or delta frame of a named layout alone in its packet so
-- far: the layout's Info code (named.piece, parse's named_code) makes the same text as
-- info_frame's pieces, in one concatenation (speed trick, measured), when it fits INFO_MAX.
-- Returns whether it did (else the entry calls info_frame: three arguments, not nine, for the
-- commonest frame).  The entry writes the piece of a packet's only frame itself (I.first: when
-- more frames follow).
local function info_layout(kind, rec, miss_n)
    local named = P.named
    if frames_in_info ~= 0 or not named then return false end
    local piece = named.piece(kind, rec, miss_n)
    if not piece then return false end
    frames_in_info, single = 1, piece
    return true
end

-- The single piece info_layout made goes into INFO, before another piece joins it.
local function spill()
    ninfo, info_len, INFO[1], single = 1, #single, single, nil
end

-- Info column: this frame's piece, piece by piece (what info_layout does not make).
local function info_frame(f, bodyend, kind, is_data, rec, list, dstb, srcb, miss_n)
    if single then spill() end
    if frames_in_info > 0 then
        if info_full then frames_dropped = frames_dropped + 1 else info_add(" ; ") end
    end
    frames_in_info = frames_in_info + 1
    info_clean = false
    if not info_full then info_pieces(f, bodyend, kind, is_data, rec, list, dstb, srcb, miss_n) end
end

-- No pieces yet: at the start of a capture, after each packet's Info (I.finish), and before a
-- packet whose previous one did not reach I.finish (a Lua error; see the entry's dissect).
local I = {}
function I.begin()
    ninfo, info_len, info_full, frames_in_info, frames_dropped = 0, 0, false, 0, 0
    info_clean, single = true, nil
end

-- The piece of the packet's first frame, which the entry got from its layout's Info code
-- (named.first_piece), when more frames follow (as info_layout's).
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

I.info_frame, I.info_layout = info_frame, info_layout
return I
