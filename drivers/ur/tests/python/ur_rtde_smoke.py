#!/usr/bin/env python3
"""ur_rtde (PyPI `ur-rtde`) against a simulated UR controller on HOST.

Protocol on stdin/stdout (one JSON object per line out, one line in):
  powers on and releases the brakes through DashboardClient, opens RTDEReceiveInterface,
  prints {"phase": "ready", ...}; waits for a line on stdin (the test has sent a movej);
  samples getActualQ() while the move runs, stops the program through the Dashboard,
  prints {"phase": "done", ...}.
Exit 77 when ur_rtde cannot be imported.
"""
import json
import sys
import time

try:
    import dashboard_client
    import rtde_receive
except ImportError as e:  # not installed
    print(f"cannot import ur_rtde: {e}", file=sys.stderr)
    sys.exit(77)


def wait_mode(dash, want, timeout=5.0):
    end = time.monotonic() + timeout
    mode = dash.robotmode()
    while want not in mode and time.monotonic() < end:
        time.sleep(0.05)
        mode = dash.robotmode()
    return mode


def main():
    host = sys.argv[1]
    dash = dashboard_client.DashboardClient(host)
    dash.connect()
    remote = dash.isInRemoteControl()
    modes = [dash.robotmode()]
    dash.powerOn()
    modes.append(wait_mode(dash, "IDLE"))
    dash.brakeRelease()
    modes.append(wait_mode(dash, "RUNNING"))
    safety = dash.safetystatus()
    rtde_r = rtde_receive.RTDEReceiveInterface(host)
    time.sleep(0.1)
    print(json.dumps({
        "phase": "ready",
        "remote": remote,
        "modes": modes,
        "safetystatus": safety,
        "q": list(rtde_r.getActualQ()),
        "robot_mode": rtde_r.getRobotMode(),
        "safety_mode": rtde_r.getSafetyMode(),
    }), flush=True)
    sys.stdin.readline()
    samples = []
    running = []
    end = time.monotonic() + 0.4
    while time.monotonic() < end:
        samples.append(list(rtde_r.getActualQ()))
        running.append(rtde_r.getRuntimeState())
        time.sleep(0.02)
    dash.stop()
    time.sleep(0.8)
    after = [list(rtde_r.getActualQ())]
    time.sleep(0.1)
    after.append(list(rtde_r.getActualQ()))
    print(json.dumps({
        "phase": "done",
        "samples": samples,
        "runtime_states": running,
        "after_stop": after,
        "runtime_state_after": rtde_r.getRuntimeState(),
        "robot_mode": rtde_r.getRobotMode(),
        "safety_mode": rtde_r.getSafetyMode(),
        "robotmode": dash.robotmode(),
    }), flush=True)
    rtde_r.disconnect()
    dash.disconnect()


main()
