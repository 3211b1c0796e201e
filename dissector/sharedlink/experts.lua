-- SharedLink dissector module: experts, a frame's expert conditions as data, and whether a frame
-- with no tree needs one for its expert infos (has_experts).  The tree builder (tree.lua) reads
-- the same conditions; this module is what the entry needs of them when no tree is built, so a
-- pass that builds none (tshark's summary pass of frames with no expert info) never loads
-- tree.lua.  Also the trees' modes (SHOWN, HIDDEN, NONE: tree.lua's head comment).
-- Loaded by sharedlink.lua (load_module); Wireshark also runs every .lua file of a plugin folder's
-- subfolders as a plugin of its own: this file then does nothing.

local token, M = ...
if type(token) ~= "table" or token.sharedlink_module ~= true then return end

local U = M.util
local tonumber = tonumber
local B_A, B_P = U.B_A, U.B_P
local valid_type, parse_long = U.valid_type, U.parse_long
local F = M.parse.F   -- the frame record (parse.lua): has_experts' argument
local VT, VN, VV, VI, VR = F.VT, F.VN, F.VV, F.VI, F.VR
local crlf_frames = true   -- see set_crlf_frames

local SHOWN, HIDDEN, NONE = 1, 2, 3

-- Whether a variable's value would get var.badvalue or var.unknown (see has_experts).
-- A frame of a named layout: its types are valid and its doubles plain decimals (the layout's
-- pattern), so only a long can fail (speed trick, measured: tonumber on a value is ~1,150
-- instructions).
local function named_values_have_experts(tv)
    for v = 1, F.nv do
        if tv[v] == 0 and not parse_long(VV[v]) then return true end
    end
    return false
end

-- Variable v's type for has_experts, or true when its name or T already has an expert (a T that
-- is not a number; a positional value past a list learnt from a declaration).  A reply's value is
-- typed by its T, else by the list its direction uses.
local function expert_type(v, list)
    if VN[v] then
        if VT[v] then return valid_type(VT[v]) or true end
        return VR[v] and M.state.list_type(list, VN[v]) or nil
    end
    if not list[VI[v] + 1] and list.decl then return true end
    return list.t[VI[v] + 1]
end

local function values_have_experts(kind, list)
    local named = F.named
    if named then return named.has_long and named_values_have_experts(named.TV) end
    for v = 1, F.nv do
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

------------------------------------------------------------------------------
-- The frame's expert conditions, as data: X[name] is true when the frame gets that expert info
-- from the tree's head or trailer (set by frame_experts, the one place each condition is written;
-- has_experts and the tree read them).  The experts of single fields and variables (an empty or
-- unknown field, a type or ordinal that is no number, var.badvalue, var.unknown) are the field's
-- own: the frame has one when F.odd, or values_have_experts.
------------------------------------------------------------------------------
local X_NAMES = { "malformed", "dst_invalid", "src_invalid", "fields", "limit", "rec_limit", "sync_late",
    "unanswered", "checksum_bad", "checksum_format", "checksum_missing", "crlf_missing" }
local X = {}
for _, name in ipairs(X_NAMES) do X[name] = false end
local function not_node(b) return b ~= nil and (b < B_A or b > B_P) end

-- The conditions of frame fr (the frame record, with the state's answers) into X; returns whether
-- any holds.  A calm frame (fr.calm: a layout's frame the entry knows has none) holds none: X is
-- cleared only when the last frame's held one (x_any; speed trick, measured: -V, the GUI).
local x_any = false
local function frame_experts(fr)
    if fr.calm then
        if x_any then
            for k = 1, #X_NAMES do X[X_NAMES[k]] = false end
            x_any = false
        end
        return false
    end
    x_any = true
    local rec, cpos, terminated = fr.rec, fr.cpos, fr.terminated
    local malformed = fr.malformed ~= nil
    X.malformed, X.dst_invalid, X.src_invalid = malformed, not_node(fr.dstb), not_node(fr.srcb)
    X.fields, X.limit = fr.odd, fr.limit ~= false
    if rec then
        X.rec_limit, X.sync_late, X.unanswered = rec.limit ~= nil, rec.late ~= nil, rec.unmatched ~= nil
    else
        X.rec_limit, X.sync_late, X.unanswered = false, false, false
    end
    X.checksum_bad = cpos ~= nil and fr.cs_status == 0
    X.checksum_format = cpos ~= nil and not fr.cs_plain
    X.checksum_missing = cpos == nil and terminated and not malformed
    -- CR LF after the ']' (the entry's fr.crlf) where CR LF frames the packet's bytes (set_crlf_frames)
    X.crlf_missing = terminated and crlf_frames and not fr.crlf
    for k = 1, #X_NAMES do
        if X[X_NAMES[k]] then return true end
    end
    x_any = false
    return false
end

------------------------------------------------------------------------------
-- Whether a frame with no tree needs one for its expert infos.
------------------------------------------------------------------------------
-- With no tree, whether frame fr's tree would carry an expert info (true when unsure): then
-- tree_frame builds it in mode NONE, on the tree Wireshark gave (which keeps no items but reports
-- the experts to Expert Information and -z expert).  The conditions tree_frame reads
-- (frame_experts), then its variables' (values_have_experts).
local function has_experts(fr)
    if frame_experts(fr) then return true end
    return values_have_experts(fr.kind, fr.list)
end

-- Whether CR LF frames the bytes of the packet being dissected (docs/fields-sharedlink.md, "Rules
-- for real sessions": serial and TCP, not a UDP datagram, which is one frame or several each
-- ending at its ']'): sharedlink.crlf.missing is noted only then.  Set once a packet.
local function set_crlf_frames(v) crlf_frames = v end

return { X = X, frame_experts = frame_experts, values_have_experts = values_have_experts,
         has_experts = has_experts, set_crlf_frames = set_crlf_frames,
         SHOWN = SHOWN, HIDDEN = HIDDEN, NONE = NONE }
