#!/bin/sh
# Opens a capture in the Wireshark GUI (under Xvfb, a throw-away HOME) with the SharedLink
# dissector loaded from this checkout, opens Expert Information from the status bar with no
# display filter, and saves a screenshot of the dialog: the check that expert infos are there
# when a capture is opened (issue 27), which tshark cannot show.
#
#   scripts/gui-expert-screenshot.sh [CAPTURE] [OUT.png]
#
# Needs wireshark-qt, xvfb, xdotool, x11-apps and imagemagick (Debian packages; not needed by
# make test). Without CAPTURE it makes the issue's capture:
#   sharedlink gen -o f.pcap --compress --drop 0.2 --bad-checksum 0.05 --seed 2
# (Expert Information should list Bad checksum 14 and No full frame within the sync interval 31).
set -eu
here=$(cd "$(dirname "$0")/.." && pwd)
work=$(mktemp -d /tmp/sharedlink-gui-XXXXXX)
cap=${1:-}
out=${2:-$here/docs/img/expert-info-on-open.png}
if [ -z "$cap" ]; then
    cap=$work/f.pcap
    "$here/.venv/bin/sharedlink" gen -o "$cap" --compress --drop 0.2 --bad-checksum 0.05 --seed 2 >/dev/null 2>&1
fi
for tool in wireshark Xvfb xdotool xwd; do
    command -v "$tool" >/dev/null || { echo "$0: $tool is missing (apt-get install wireshark-qt xvfb xdotool x11-apps imagemagick)" >&2; exit 2; }
done
display=:$((90 + $$ % 100))
Xvfb "$display" -screen 0 1400x900x24 >/dev/null 2>&1 &
xvfb=$!
trap 'kill $ws $xvfb 2>/dev/null; rm -rf "$work"' EXIT
ws=
sleep 1
export DISPLAY="$display" HOME="$work/home"
mkdir -p "$HOME"
wireshark -X "lua_script:$here/dissector/sharedlink.lua" -r "$cap" >"$work/wireshark.log" 2>&1 &
ws=$!
# wait until the main window shows the file
i=0
until xdotool search --name "$(basename "$cap")" >/dev/null 2>&1; do
    i=$((i + 1)); [ $i -lt 60 ] || { echo "$0: Wireshark did not open $cap" >&2; exit 1; }
    sleep 1
done
sleep 3
xdotool mousemove 37 559 click 1  # the expert indicator at the status bar's left end
i=0
until xdotool search --name "Expert Information" >/dev/null 2>&1; do
    i=$((i + 1)); [ $i -lt 20 ] || { echo "$0: Expert Information did not open" >&2; exit 1; }
    sleep 1
done
sleep 2
for w in $(xdotool search --name "Expert Information"); do xdotool windowmove "$w" 0 0 windowsize "$w" 1390 480; done
sleep 2
mkdir -p "$(dirname "$out")"
xwd -root -silent | /usr/bin/convert xwd:- -crop 1400x472+0+0 "$out"
echo "$out"
