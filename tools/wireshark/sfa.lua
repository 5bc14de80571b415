-- Wireshark / tshark dissector of the SFA wire protocol (INPUT, OUTPUT, extended OUTPUT, ACK) and of
-- the project's authenticated envelope (docs/protocol.md, listener/codec.py, listener/auth.py).
--
--   tshark -X lua_script:tools/wireshark/sfa.lua -r capture.pcap
--   wireshark -X lua_script:tools/wireshark/sfa.lua capture.pcap
--   (or copy this file into ~/.local/lib/wireshark/plugins/)
--
-- Registered on the default ports of listener/defaults.py and listener/config/*.toml: UDP 48000
-- (INPUT, to the listener), 48001 (OUTPUT to the OBCU, ACK from it), and the simulator's interface
-- module source ports 47000-47003 (interface_modules/scenario.py). The port table is consulted before
-- Wireshark's heuristic dissectors and by the lower port first, which is why the control module's
-- source port 47000 (HCrt's registered port) and the IMU datagrams (CIGI's heuristic) were misread
-- before: this dissector takes those ports over. The ports are preferences (Edit > Preferences >
-- Protocols > SFA, or `-o sfa.input_port:NNNN`); a heuristic dissector also recognises INPUT
-- datagrams (and their authenticated form) on any port, by their exact header-length-form rule.
--
-- Field names follow the codec (sfa.imu.ax, sfa.output.arc_length, ...), units are in the labels.
-- Licence: the project's. Wireshark loads Lua dissectors without linking, so no GPL obligation
-- arises for the project's code.

local sfa = Proto("sfa", "SFA train positioning protocol")

-- --------------------------------------------------------------------------------------------------
-- Preferences

sfa.prefs.input_port = Pref.uint("Listener input port", 48000, "UDP port of INPUT_PROTOCOL (input.port)")
sfa.prefs.obcu_port = Pref.uint("OBCU port", 48001, "UDP port the OBCU receives outputs on (link.obcu_port)")
sfa.prefs.module_ports = Pref.range("Interface module source ports", "47000-47003",
    "source ports of the interface modules (the simulator's defaults); empty: none", 65535)
sfa.prefs.big_endian = Pref.bool("Big-endian variant", false,
    "the optional big-endian byte order (off by default, as in the protocol)")
sfa.prefs.auth_tag_bytes = Pref.uint("Authentication tag length [bytes]", 16,
    "auth.tag_bytes of the authenticated links (16..32); INPUT datagrams find it from their length")

-- --------------------------------------------------------------------------------------------------
-- Fields

local SENSOR_TYPES = { [1] = "IMU", [2] = "ODOMETER", [3] = "GPS", [8] = "GROUND TRUTH", [9] = "STROBE",
                       [10] = "STOP" }
local FIX_QUALITY = { [0] = "no fix", [1] = "GPS", [2] = "DGPS", [3] = "PPS", [4] = "RTK fixed",
                      [5] = "RTK float", [6] = "estimated", [7] = "manual", [8] = "simulation" }
local FILTER_STATUS = { [0] = "INITIALISING", [1] = "NOMINAL", [2] = "DEGRADED", [3] = "LOST" }

local F = {}
local function field(list, key, pf) F[key] = pf; list[#list + 1] = pf end
local fl = {}
field(fl, "message", ProtoField.string("sfa.message", "Message"))
field(fl, "sensor_type", ProtoField.uint8("sfa.input.sensor_type", "SENSOR_TYPE", base.DEC, SENSOR_TYPES))
field(fl, "input_seq", ProtoField.uint16("sfa.input.seq", "SEQ", base.DEC))
field(fl, "n_int", ProtoField.uint8("sfa.input.n_int", "N_INT (int32 that follow)", base.DEC))
field(fl, "n_double", ProtoField.uint8("sfa.input.n_double", "N_DOUBLE (float64 after the ints)", base.DEC))

-- payload fields per SENSOR_TYPE: {name, label, kind}; kind "i" int32, "d" float64
local PAYLOAD = {
  [1] = { prefix = "imu", ints = {}, doubles = {
      { "ax", "ax, specific force forward [m/s^2]" }, { "ay", "ay, specific force right [m/s^2]" },
      { "az", "az, specific force down [m/s^2]" }, { "gx", "gx, roll rate [rad/s]" },
      { "gy", "gy, pitch rate [rad/s]" }, { "gz", "gz, yaw rate [rad/s]" },
      { "epoch", "epoch, sampling time [s]" } }, int_forms = { 0 }, n_required = 6 },
  [2] = { prefix = "odometer", ints = {}, doubles = {
      { "speed", "speed, signed, > 0 forward [m/s]" }, { "sigma", "sigma, 1-sigma of speed [m/s]" },
      { "epoch", "epoch, sampling time [s]" } }, int_forms = { 0 }, n_required = 2 },
  [3] = { prefix = "gps", ints = {
      { "fix_quality", "fix_quality (NMEA GGA)", FIX_QUALITY }, { "num_sv", "num_sv, satellites used" } },
    doubles = {
      { "lat", "lat, WGS84 latitude [deg]" }, { "lon", "lon, WGS84 longitude [deg]" },
      { "alt", "alt, above MSL [m]" }, { "sigma_h", "sigma_h, horizontal 1-sigma per axis [m]" },
      { "epoch", "epoch, sampling time [s]" } }, int_forms = { 0, 2 }, n_required = 3 },
  [8] = { prefix = "ground_truth", ints = { { "line_id", "line_id, track database line" } }, doubles = {
      { "vx", "vx, body velocity forward [m/s]" }, { "vy", "vy, body velocity right [m/s]" },
      { "vz", "vz, body velocity down [m/s]" }, { "arc_length", "arc_length [m]" },
      { "epoch", "epoch [s]" } }, int_forms = { 0, 1 }, n_required = 4 },
  [9] = { prefix = "strobe", ints = {}, doubles = { { "timestamp", "timestamp, sensor-set time [s]" } },
    int_forms = { 0 }, n_required = 1 },
  [10] = { prefix = "stop", ints = {}, doubles = {}, int_forms = { 0 }, n_required = 0 },
}
for _, lay in pairs(PAYLOAD) do
  lay.int_fields, lay.double_fields = {}, {}
  for i, d in ipairs(lay.ints) do
    lay.int_fields[i] = ProtoField.int32("sfa." .. lay.prefix .. "." .. d[1], d[2], base.DEC, d[3])
    fl[#fl + 1] = lay.int_fields[i]
  end
  for i, d in ipairs(lay.doubles) do
    lay.double_fields[i] = ProtoField.double("sfa." .. lay.prefix .. "." .. d[1], d[2])
    fl[#fl + 1] = lay.double_fields[i]
  end
end

-- the codec's physical ranges (listener/codec.py FIELD_RANGES, listener/limits.py; docs/protocol.md):
-- {lo, hi, unit, lo_open}; tests/test_wireshark_dissector.py checks this table against the codec's
local RANGES = {
  ax = { -156.9064, 156.9064, "m/s^2" }, ay = { -156.9064, 156.9064, "m/s^2" },
  az = { -156.9064, 156.9064, "m/s^2" },
  gx = { -35.0, 35.0, "rad/s" }, gy = { -35.0, 35.0, "rad/s" }, gz = { -35.0, 35.0, "rad/s" },
  speed = { -150.0, 150.0, "m/s" }, sigma = { 0.0, 50.0, "m/s", true },
  lat = { -90.0, 90.0, "deg" }, lon = { -180.0, 180.0, "deg" }, alt = { -500.0, 9000.0, "m" },
  sigma_h = { 0.0, 100000.0, "m", true },
  fix_quality = { 0, 8, "" }, num_sv = { 0, 255, "" },
  vx = { -150.0, 150.0, "m/s" }, vy = { -150.0, 150.0, "m/s" }, vz = { -150.0, 150.0, "m/s" },
  arc_length = { -1000.0, 100000000.0, "m" }, line_id = { 0, 2147483647, "" },
  epoch = { 0.0, 10000000000.0, "s" }, timestamp = { 0.0, 10000000000.0, "s" },
}

field(fl, "out_seq", ProtoField.uint16("sfa.output.seq", "SEQ", base.DEC))
field(fl, "out_epoch", ProtoField.double("sfa.output.epoch", "EPOCH, time of the estimate [s]"))
field(fl, "out_arc", ProtoField.double("sfa.output.arc_length", "FU_ARC_LEN, arc length [m]"))
field(fl, "out_speed", ProtoField.double("sfa.output.speed", "SPEED, > 0 forward [m/s]"))
field(fl, "out_low", ProtoField.double("sfa.output.interval_low", "INTERVAL_LOW, confidence interval [m]"))
field(fl, "out_high", ProtoField.double("sfa.output.interval_high", "INTERVAL_HIGH, confidence interval [m]"))
field(fl, "out_status", ProtoField.uint8("sfa.output.status", "STATUS (filter status)", base.DEC, FILTER_STATUS))
field(fl, "out_line", ProtoField.int32("sfa.output.line_id", "LINE_ID (-1: unknown)", base.DEC))
field(fl, "ack_seq", ProtoField.uint16("sfa.ack.seq", "SEQ acknowledged (newest received)", base.DEC))
field(fl, "auth_magic", ProtoField.uint8("sfa.auth.magic", "MAGIC", base.HEX))
field(fl, "auth_key_id", ProtoField.uint8("sfa.auth.key_id", "KEY_ID", base.DEC))
field(fl, "auth_epoch", ProtoField.uint32("sfa.auth.epoch", "EPOCH (SEQ wraps / restarts)", base.DEC))
field(fl, "auth_payload_len", ProtoField.uint16("sfa.auth.payload_length", "Payload length [bytes]", base.DEC))
field(fl, "auth_tag", ProtoField.bytes("sfa.auth.tag", "TAG, truncated HMAC-SHA256 (not verified)"))
sfa.fields = fl

local ef_malformed = ProtoExpert.new("sfa.malformed", "Malformed SFA datagram", expert.group.MALFORMED,
                                     expert.severity.ERROR)
local ef_nonfinite = ProtoExpert.new("sfa.non_finite", "Non-finite float64 (the codec rejects it)",
                                     expert.group.MALFORMED, expert.severity.ERROR)
sfa.experts = { ef_malformed, ef_nonfinite }

-- --------------------------------------------------------------------------------------------------
-- Helpers

local function big() return sfa.prefs.big_endian end
local function add(tree, pf, range)
  if big() then return tree:add(pf, range) end
  return tree:add_le(pf, range)
end
local function u16(r) if big() then return r:uint() end return r:le_uint() end
local function f64(r) if big() then return r:float() end return r:le_float() end
local function finite(x) return x == x and x ~= math.huge and x ~= -math.huge end
local function repr(x)  -- Python's spelling of the non-finite values (the codec's messages)
  if x ~= x then return "nan" elseif x == math.huge then return "inf" elseif x == -math.huge then return "-inf" end
  return string.format("%.17g", x)
end
local function i32(r) if big() then return r:int() end return r:le_int() end

-- the codec's per-field check of one payload value: nil, or "non_finite: ..." / "range: ..."
local function value_problem(where, name, x, is_int)
  if not is_int and not finite(x) then
    return string.format("non_finite: %s: %s=%s is not finite", where, name, repr(x))
  end
  local r = RANGES[name]
  if r == nil then return nil end
  local lo_ok = (r[4] and x > r[1]) or (not r[4] and x >= r[1])
  if lo_ok and x <= r[2] then return nil end
  -- the value to the last bit (%.17g round-trips; Python's repr is the shortest such), bounds as the codec's
  local vfmt, bfmt = is_int and "%d" or "%.17g", is_int and "%d" or "%.10g"
  local text = string.format("range: %s: %s=" .. vfmt .. " outside %s" .. bfmt .. ", " .. bfmt .. "] %s", where,
                             name, x, r[4] and "(" or "[", r[1], r[2], r[3])
  return (text:gsub("%s+$", ""))
end

local function input_len(tvb, off)
  return 5 + 4 * tvb(off + 3, 1):uint() + 8 * tvb(off + 4, 1):uint()
end

-- why an INPUT datagram of ``len`` bytes at ``off`` is malformed, or nil: the codec's checks, in its
-- order, each message starting with the codec's RejectReason (short, type, length, form)
local function input_problem(tvb, off, len)
  if len < 5 then return "short: " .. len .. " bytes, the header alone is 5" end
  local t, ni, nd = tvb(off, 1):uint(), tvb(off + 3, 1):uint(), tvb(off + 4, 1):uint()
  local lay = PAYLOAD[t]
  if lay == nil then return "type: unknown SENSOR_TYPE " .. t end
  local name = SENSOR_TYPES[t]:gsub(" ", "_")
  local expect = 5 + 4 * ni + 8 * nd
  if len ~= expect then
    return string.format("length: %s: %d bytes, header N_INT=%d N_DOUBLE=%d says %d", name, len, ni, nd, expect)
  end
  local int_ok, allowed = false, {}
  for _, k in ipairs(lay.int_forms) do
    if k == ni then int_ok = true end
    for d = lay.n_required, #lay.doubles do allowed[#allowed + 1] = string.format("(%d,%d)", k, d) end
  end
  if not int_ok or nd < lay.n_required or nd > #lay.doubles then
    return string.format("form: %s: (N_INT, N_DOUBLE)=(%d,%d) not allowed; allowed %s", name, ni, nd,
                         table.concat(allowed, ", "))
  end
  return nil
end

local function dissect_input(tvb, pinfo, tree, off, len)
  local sub = tree:add(sfa, tvb(off, len), "SFA INPUT")
  sub:add(F.message, "INPUT")
  if len >= 1 then add(sub, F.sensor_type, tvb(off, 1)) end
  if len >= 3 then add(sub, F.input_seq, tvb(off + 1, 2)) end
  if len >= 5 then add(sub, F.n_int, tvb(off + 3, 1)); add(sub, F.n_double, tvb(off + 4, 1)) end
  local problem = input_problem(tvb, off, len)
  if problem then
    sub:add_proto_expert_info(ef_malformed, problem)
    return "INPUT malformed (" .. problem .. ")"
  end
  local t, ni, nd = tvb(off, 1):uint(), tvb(off + 3, 1):uint(), tvb(off + 4, 1):uint()
  local lay = PAYLOAD[t]
  local seq = u16(tvb(off + 1, 2))
  sub:append_text(string.format(", %s, SEQ %d", SENSOR_TYPES[t], seq))
  local where = string.format("%s(%d,%d)", SENSOR_TYPES[t] == "GROUND TRUTH" and "GROUND_TRUTH" or SENSOR_TYPES[t],
                              ni, nd)
  local problem_text = nil
  local function check(item, name, x, is_int)
    if problem_text then return end
    local why = value_problem(where, name, x, is_int)
    if why then
      problem_text = why
      item:add_proto_expert_info(why:sub(1, 10) == "non_finite" and ef_nonfinite or ef_malformed, why)
    end
  end
  local p = off + 5
  for i = 1, ni do
    local item = add(sub, lay.int_fields[i], tvb(p, 4))
    check(item, lay.ints[i][1], i32(tvb(p, 4)), true)
    p = p + 4
  end
  local summary = {}
  for i = 1, nd do
    local item = add(sub, lay.double_fields[i], tvb(p, 8))
    local x = f64(tvb(p, 8))
    check(item, lay.doubles[i][1], x, false)
    if i <= 3 then summary[#summary + 1] = string.format("%s=%.10g", lay.doubles[i][1], x) end
    p = p + 8
  end
  if problem_text then return string.format("%s SEQ=%d rejected (%s)", SENSOR_TYPES[t], seq, problem_text) end
  return string.format("%s SEQ=%d %s", SENSOR_TYPES[t], seq, table.concat(summary, " "))
end

local function dissect_output(tvb, pinfo, tree, off, len)
  local extended = len == 47
  local sub = tree:add(sfa, tvb(off, len), extended and "SFA OUTPUT (extended)" or "SFA OUTPUT")
  sub:add(F.message, extended and "OUTPUT_EXTENDED" or "OUTPUT")
  if len ~= 18 and len ~= 47 then
    sub:add_proto_expert_info(ef_malformed, "length: OUTPUT: " .. len .. " bytes, expected 18")  -- or 47
    return "OUTPUT malformed (" .. len .. " bytes)"
  end
  add(sub, F.out_seq, tvb(off, 2))
  local items = { add(sub, F.out_epoch, tvb(off + 2, 8)), add(sub, F.out_arc, tvb(off + 10, 8)) }
  local seq, arc = u16(tvb(off, 2)), f64(tvb(off + 10, 8))
  local text = string.format("OUTPUT SEQ=%d arc_length=%.3f m", seq, arc)
  if extended then
    items[#items + 1] = add(sub, F.out_speed, tvb(off + 18, 8))
    items[#items + 1] = add(sub, F.out_low, tvb(off + 26, 8))
    items[#items + 1] = add(sub, F.out_high, tvb(off + 34, 8))
    add(sub, F.out_status, tvb(off + 42, 1))
    add(sub, F.out_line, tvb(off + 43, 4))
    local st = tvb(off + 42, 1):uint()
    text = string.format("OUTPUT_EXTENDED SEQ=%d arc_length=%.3f m speed=%.3f m/s status=%s", seq, arc,
                         f64(tvb(off + 18, 8)), FILTER_STATUS[st] or tostring(st))
  end
  local where = extended and "OUTPUT_EXTENDED" or "OUTPUT"
  if extended and i32(tvb(off + 43, 4)) < -1 then  -- the codec's first check of the extension
    local why = string.format("range: %s: line_id=%d (only -1 means none)", where, i32(tvb(off + 43, 4)))
    sub:add_proto_expert_info(ef_malformed, why)
    return text .. " rejected (" .. why .. ")"
  end
  local names = { "epoch", "arc_length", "speed", "interval_low", "interval_high" }
  for k, item in ipairs(items) do
    local x = f64(tvb(off + 2 + 8 * (k - 1), 8))
    if not finite(x) then
      local why = string.format("non_finite: %s: %s=%s is not finite", where, names[k], repr(x))
      item:add_proto_expert_info(ef_nonfinite, why)
      return text .. " rejected (" .. why .. ")"
    end
  end
  if extended then
    local low, high = f64(tvb(off + 26, 8)), f64(tvb(off + 34, 8))
    if not (low <= arc and arc <= high) then
      local why = string.format("range: %s: interval [%.17g, %.17g] does not contain arc_length=%.17g", where,
                                low, high, arc)
      sub:add_proto_expert_info(ef_malformed, why)
      return text .. " rejected (" .. why .. ")"
    end
  end
  return text
end

local function dissect_ack(tvb, pinfo, tree, off, len)
  local sub = tree:add(sfa, tvb(off, len), "SFA ACK")
  sub:add(F.message, "ACK")
  if len ~= 2 then
    sub:add_proto_expert_info(ef_malformed, "length: ACK: " .. len .. " bytes, expected 2")
    return "ACK malformed (" .. len .. " bytes)"
  end
  add(sub, F.ack_seq, tvb(off, 2))
  return string.format("ACK SEQ=%d", u16(tvb(off, 2)))
end

-- the tag length of a wrapped INPUT datagram follows from the inner header; nil if none fits
local function wrapped_input_tag(tvb, len)
  if len < 6 + 5 + 16 then return nil end
  local inner = input_len(tvb, 6)
  local tag = len - 6 - inner
  if tag >= 16 and tag <= 32 and input_problem(tvb, 6, inner) == nil then return tag end
  return nil
end

local function dissect_auth(tvb, pinfo, tree, inner_fn, tag)
  local len = tvb:len()
  local sub = tree:add(sfa, tvb(0, len), "SFA authenticated envelope")
  if tag == nil or len < 6 + tag then
    sub:add_proto_expert_info(ef_malformed, "authenticated envelope too short for its tag")
    return "AUTH malformed"
  end
  sub:add(F.auth_magic, tvb(0, 1))
  sub:add(F.auth_key_id, tvb(1, 1))
  sub:add_le(F.auth_epoch, tvb(2, 4))
  sub:add(F.auth_payload_len, len - 6 - tag)
  local text = inner_fn(tvb, pinfo, sub, 6, len - 6 - tag)
  sub:add(F.auth_tag, tvb(len - tag, tag))
  return string.format("AUTH key %d epoch %d: %s", tvb(1, 1):uint(), tvb(2, 4):le_uint(), text)
end

-- --------------------------------------------------------------------------------------------------
-- Direction: by port (the preferences), then by content

local function in_module_ports(port)
  local r = sfa.prefs.module_ports
  if r == nil then return false end
  for part in tostring(r):gmatch("[^,]+") do
    local a, b = part:match("^%s*(%d+)%s*%-%s*(%d+)%s*$")
    if a then
      if port >= tonumber(a) and port <= tonumber(b) then return true end
    else
      local one = part:match("^%s*(%d+)%s*$")
      if one and tonumber(one) == port then return true end
    end
  end
  return false
end

local function finish(pinfo, text)
  pinfo.cols.protocol = "SFA"
  pinfo.cols.info = text
end

function sfa.dissector(tvb, pinfo, tree)
  local len = tvb:len()
  if len == 0 then return 0 end
  local sport, dport = pinfo.src_port, pinfo.dst_port
  local obcu = sfa.prefs.obcu_port
  local wrapped = tvb(0, 1):uint() == 0xA5
  local text
  if dport == obcu then
    if len == 18 or len == 47 or not wrapped then
      text = dissect_output(tvb, pinfo, tree, 0, len)
    else
      text = dissect_auth(tvb, pinfo, tree, dissect_output, sfa.prefs.auth_tag_bytes)
    end
  elseif sport == obcu then
    if len == 2 or not wrapped then
      text = dissect_ack(tvb, pinfo, tree, 0, len)
    else
      text = dissect_auth(tvb, pinfo, tree, dissect_ack, sfa.prefs.auth_tag_bytes)
    end
  elseif dport == sfa.prefs.input_port or in_module_ports(sport) then
    if wrapped then
      text = dissect_auth(tvb, pinfo, tree, dissect_input, wrapped_input_tag(tvb, len))
    else
      text = dissect_input(tvb, pinfo, tree, 0, len)
    end
  else
    return 0
  end
  finish(pinfo, text)
  return len
end

-- any port: only what the codec would accept as INPUT (exact length, allowed form), plain or wrapped
local function heuristic(tvb, pinfo, tree)
  local len = tvb:len()
  if len < 5 then return false end
  local text
  if tvb(0, 1):uint() == 0xA5 then
    local tag = wrapped_input_tag(tvb, len)
    if tag == nil then return false end
    text = dissect_auth(tvb, pinfo, tree, dissect_input, tag)
  else
    if input_len(tvb, 0) ~= len or input_problem(tvb, 0, len) ~= nil then return false end
    text = dissect_input(tvb, pinfo, tree, 0, len)
  end
  finish(pinfo, text)
  return true
end

-- --------------------------------------------------------------------------------------------------
-- Registration (again whenever the port preferences change)

local udp_table = DissectorTable.get("udp.port")
local registered = {}

local function register_ports()
  for _, port in ipairs(registered) do udp_table:remove(port, sfa) end
  registered = {}
  local function reg(port)
    if port and port > 0 and port <= 65535 then udp_table:add(port, sfa); registered[#registered + 1] = port end
  end
  reg(sfa.prefs.input_port)
  reg(sfa.prefs.obcu_port)
  for part in tostring(sfa.prefs.module_ports or ""):gmatch("[^,]+") do
    local a, b = part:match("^%s*(%d+)%s*%-%s*(%d+)%s*$")
    if a then
      for p = tonumber(a), math.min(tonumber(b), tonumber(a) + 255) do reg(p) end
    else
      reg(tonumber(part:match("^%s*(%d+)%s*$")))
    end
  end
end

function sfa.prefs_changed() register_ports() end

register_ports()
sfa:register_heuristic("udp", heuristic)
