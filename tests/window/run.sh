#!/usr/bin/env bash
# The `forest` example in a real window: Xvfb (an X server in memory),
# Bevy's winit/X11 path and Mesa's software Vulkan presenting to it. Keys go
# in through XTEST (xdotool) as a user's would; screenshots of the screen
# (xwd) must change the way each key says:
#   F3      the overlay's stats panel appears (top left) and its colours
#   ]       pixel error up: the panel's first line (ε) changes
#   [       back down: that line is the same pixels as before
#   L       LOD off: every needle a prism; the panel's prism and triangle
#           counts (its third line) change, and come back with L again
#   Esc     the app exits with status 0
# and a second run must exit with status 0 when its window is closed
# (WM_DELETE_WINDOW, what a window manager's close button sends).
# Pictures land in target/test-output/window/. Needs xvfb, xdotool, x11-apps
# (.ci/test installs them) and the example built.
set -euo pipefail
cd "$(dirname "$0")/../.."
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$HOME/.cache/bevy_conifer_lod/target}"
FOREST="$CARGO_TARGET_DIR/debug/examples/forest"
TOOL="python3 tests/window/xtool.py"
OUT=target/test-output/window
rm -rf "$OUT"; mkdir -p "$OUT"
[ -x "$FOREST" ] || { echo "build the forest example first"; exit 1; }

DISPLAY_NUMBER=97
while [ -e "/tmp/.X${DISPLAY_NUMBER}-lock" ]; do DISPLAY_NUMBER=$((DISPLAY_NUMBER + 1)); done
Xvfb ":$DISPLAY_NUMBER" -screen 0 640x360x24 -nolisten tcp >"$OUT/xvfb.log" 2>&1 &
XVFB=$!
APP=""
cleanup() { [ -n "$APP" ] && kill "$APP" 2>/dev/null; kill "$XVFB" 2>/dev/null || true; }
trap cleanup EXIT
export DISPLAY=":$DISPLAY_NUMBER"
for _ in $(seq 50); do xdotool getdisplaygeometry >/dev/null 2>&1 && break; sleep 0.1; done

# The window's origin is the screen's: regions below are window pixels.
SCENE="0 0 480 270"       # the whole window
PANEL="8 8 390 95"        # the stats panel
EPSILON_LINE="8 8 390 20" # its first line: "conifer LOD   pixel error 1.00 px"
PRISMS_LINE="8 47 390 16" # its third line: "prisms 0   triangles 0"

# A light forest (33 trees of 1,000 needles): on lavapipe with two cores a
# frame of the 132-tree, 4,000-needle forest took 8 s with LOD on and over
# 40 s with LOD off, and a key shows on screen about three frames after it
# is pressed, so `L`'s picture came after the old 120 s wait (measured
# 2026-12-02 with the forest's headless `median_frame_ms`).
start() { # $1: log name
    "$FOREST" --size 480x270 --spacing 60 --grow --needles 1000 >"$OUT/$1.log" 2>&1 &
    APP=$!
    for _ in $(seq 600); do
        grep -q "forest ready" "$OUT/$1.log" && break
        kill -0 "$APP" 2>/dev/null || { cat "$OUT/$1.log"; echo "the forest exited before it was ready"; exit 1; }
        sleep 0.5
    done
    grep -q "forest ready" "$OUT/$1.log" || { echo "the forest was not ready in 300 s"; exit 1; }
    WINDOW=$(xdotool search --sync --name "conifer forest" | head -1)
    xdotool windowfocus --sync "$WINDOW"
    sleep 10 # pipelines compile on the first frames
}
shot() { xwd -root -silent >"$OUT/$1.xwd"; $TOOL png "$OUT/$1.xwd" "$OUT/$1.png"; }
press() { for key in "$@"; do xdotool keydown "$key"; sleep 0.4; xdotool keyup "$key"; sleep 0.4; done; }
# wait_for NAME CONDITION: screenshots NAME until CONDITION (a shell test
# that may read $OUT/NAME.xwd) holds, at most about 240 s.
wait_for() {
    local name=$1 condition=$2
    for _ in $(seq 120); do
        shot "$name"
        if eval "$condition"; then echo "ok: $name"; return 0; fi
        sleep 2
    done
    echo "FAILED: $name: $condition"; exit 1
}
above() { python3 -c "import sys; sys.exit(0 if $1 > $2 else 1)"; }
exits_cleanly() { # $1: what made it exit
    for _ in $(seq 120); do kill -0 "$APP" 2>/dev/null || break; sleep 0.5; done
    if kill -0 "$APP" 2>/dev/null; then echo "FAILED: still running 60 s after $1"; exit 1; fi
    local status=0; wait "$APP" || status=$?; APP=""
    [ "$status" -eq 0 ] || { echo "FAILED: exit status $status after $1"; exit 1; }
    echo "ok: exit status 0 after $1"
}

start keys
# The first frame can take longer than `start`'s wait (every species'
# pipelines compile on lavapipe): the window shows one flat clear colour
# until then. A dark one taken as the base made every later comparison of
# the panel's region compare the scene with itself; a light one (the sky
# since `Hdr`) let the panel's wait below pass on the scene appearing
# before the panel did, and the ε line then differed from a panel-less
# picture. The base is a drawn frame: the window's pixels vary.
wait_for base "above \$($TOOL spread $OUT/base.xwd $SCENE) 0.03 && above \$($TOOL brightness $OUT/base.xwd $PANEL) 0.3"
press F3
wait_for overlay "above \$($TOOL differ $OUT/base.xwd $OUT/overlay.xwd $PANEL) 0.3"
press bracketright
wait_for epsilon_up "above \$($TOOL differ $OUT/overlay.xwd $OUT/epsilon_up.xwd $EPSILON_LINE) 0.01"
press bracketleft
wait_for epsilon_back "above 0.002 \$($TOOL differ $OUT/overlay.xwd $OUT/epsilon_back.xwd $EPSILON_LINE)"
press l
wait_for lod_off "above \$($TOOL differ $OUT/epsilon_back.xwd $OUT/lod_off.xwd $PRISMS_LINE) 0.02"
press l
wait_for lod_on "above 0.002 \$($TOOL differ $OUT/epsilon_back.xwd $OUT/lod_on.xwd $PRISMS_LINE)"
press Escape
exits_cleanly Esc

start close
$TOOL close "$WINDOW"
exits_cleanly "the window was closed"
