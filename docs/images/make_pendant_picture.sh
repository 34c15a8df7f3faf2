#!/bin/bash
# The README's pendant picture from a real system: the iiwa, two taught points and a program, the page with J2
# held (its button green), in headless Chromium.
cd "$(dirname "$0")/../.."; J=.venv/bin/jara-arm
DIR=$(mktemp -d)
$J up --robot iiwa --program-dir "$DIR" > /tmp/shots_up.log 2>&1 &
UP=$!
$J wait alive --timeout 60
$J call servoON; $J call setSpeedJoint '{"spdRatio": 60}'
$J call teach '{"name": "ready"}'
$J call movePTPJointAbs '{"jointPoints": [0.6, 0.5, 0.0, -1.3, 0.0, 1.2, 0.0]}'
$J call teach '{"name": "pick"}'
cat >> "$DIR/arm0.program.yaml" <<'YAML'
  - ptp: ready
    speed: 50
  - lin: pick
    speed: 30
  - wait: 0.5
  - loop: 2
    steps:
      - ptp: ready
      - ptp: pick
YAML
sed -i 's/^steps: \[\]$/steps:/' "$DIR/arm0.program.yaml"
$J pendant --port 8090 --program "$DIR/arm0.program.yaml" > /tmp/shots_pendant.log 2>&1 &
PENDANT=$!
sleep 3
.venv/bin/python - <<'PY'
import json, sys, time
from pathlib import Path
sys.path.insert(0, ".")
from tests.test_view import Browser
from tests.test_pendant import button_centre, mouse
b = Browser(Path("/tmp/jara-arm-pictures"), width=1280, height=800)
try:
    b.open("http://127.0.0.1:8090/"); time.sleep(6)
    x, y = button_centre(b, "-", 1)  # J2 -
    mouse(b, "mouseMoved", x, y); mouse(b, "mousePressed", x, y); time.sleep(0.8)
    b.shot(Path("docs/images/pendant.png"))
    mouse(b, "mouseReleased", x, y)
finally:
    b.close()
PY
kill -INT $PENDANT $UP; wait
