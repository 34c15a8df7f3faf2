#!/bin/bash
# README pictures from a real system: two arms, an obstacle, a PTP and a LIN, the view and a plot.
cd "$(dirname "$0")/../.."; J=.venv/bin/jara-arm
$J up --arm arm0:iiwa --arm arm1:scara4 --obstacle 0.45,-0.35,0.15,0.08,0.08,0.15 > /tmp/shots_up.log 2>&1 &
UP=$!
$J wait --arm arm0 alive --timeout 60 && $J wait --arm arm1 alive --timeout 60
$J view --port 8090 > /tmp/shots_view.log 2>&1 &
VIEW=$!
for a in arm0 arm1; do $J call --arm $a servoON; $J call --arm $a setSpeedJoint 60; $J call --arm $a setSpeedCartesian 60; done
$J plot --arm arm0 --seconds 6 -o docs/images/plot.png --size 1600x1100 --no-show > /tmp/shots_plot.log 2>&1 &
PLOT=$!
sleep 1.5
$J call --arm arm0 movePTPJointAbs '{"jointPoints": [0.6, 0.5, 0.0, -1.3, 0.0, 1.2, 0.0]}'
$J call --arm arm1 movePTPJointAbs '{"jointPoints": [0.5, -0.8, -0.05, 0.3]}'
$J wait --arm arm0 idle --timeout 20
$J call --arm arm0 moveLinearCartesianRel '{"carPoint": {"carPos": [[1,0,0,0],[0,1,0,-0.25],[0,0,1,0.05]], "elbow": 0, "structFlag": 0}}'
sleep 0.3
.venv/bin/python - <<'PY'
import sys, time
from pathlib import Path
sys.path.insert(0, ".")
from tests.test_view import Browser, settled_shot
b = Browser(Path("/tmp/jara-arm-pictures")); 
try:
    b.open("http://127.0.0.1:8090"); time.sleep(4)
    b.shot(Path("docs/images/view.png"))
finally:
    b.close()
PY
wait $PLOT; cat /tmp/shots_plot.log | tail -3
kill -INT $VIEW; kill -INT $UP; wait
