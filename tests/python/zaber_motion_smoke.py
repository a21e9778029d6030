"""Drive a simulated cellcal Zaber stage with Zaber's official Motion Library (zaber-motion).

Usage: zaber_motion_smoke.py PORT FULL_STEP_MM DEVICE_ID

Exit code 77: zaber_motion is not installed.

Detects the device on PORT, homes it, moves to 10 mm and reads the position back. Prints one
JSON line with what it saw; exits non-zero on any failure.

Offline by design: device identification against Zaber's device database (normally downloaded
from the internet) is switched off (`identify_devices=False`) and the database source is set to
an unreachable loopback address, so nothing here can reach the network. Without identification
the library refuses unit conversion, so mm are converted here from the device's own
`resolution` and the product's full-step size (FULL_STEP_MM, from cellcal's product table),
exactly as cellcal's driver does.
"""

import json
import sys
import time

try:
    from zaber_motion import DeviceDbSourceType, Library
    from zaber_motion.ascii import Connection
except ImportError as e:  # the caller turns this exit code into a skip notice
    print(f"zaber_motion not importable: {e}", file=sys.stderr)
    sys.exit(77)


def main() -> int:
    port, full_step_mm, device_id = sys.argv[1], float(sys.argv[2]), int(sys.argv[3])
    Library.set_device_db_source(DeviceDbSourceType.WEB_SERVICE, "http://127.0.0.1:9/")
    out = {"zaber_motion": _version()}
    t0 = time.monotonic()
    with Connection.open_serial_port(port) as conn:
        out["t_open_s"] = round(time.monotonic() - t0, 3)
        devices = conn.detect_devices(identify_devices=False)
        out["t_detect_s"] = round(time.monotonic() - t0, 3)
        out["detected"] = len(devices)
        assert len(devices) == 1, f"expected one device, found {len(devices)}"
        dev = devices[0]
        axis = dev.get_axis(1)
        out["device_id"] = int(dev.settings.get("device.id"))
        assert out["device_id"] == device_id, out
        out["serial"] = int(dev.settings.get("system.serial"))
        out["axis_count"] = int(dev.settings.get("system.axiscount"))
        resolution = int(axis.settings.get("resolution"))
        out["resolution"] = resolution
        steps_per_mm = resolution / full_step_mm
        out["warnings_before_home"] = sorted(axis.warnings.get_flags())
        axis.home()  # waits until idle
        out["warnings_after_home"] = sorted(axis.warnings.get_flags())
        axis.move_absolute(round(10.0 * steps_per_mm))  # native microsteps; waits until idle
        pos_steps = axis.get_position()
        out["pos_steps"] = pos_steps
        out["pos_mm"] = pos_steps / steps_per_mm
        out["busy"] = axis.is_busy()
        out["t_done_s"] = round(time.monotonic() - t0, 3)
    print(json.dumps(out))
    assert abs(out["pos_mm"] - 10.0) <= 1.0 / steps_per_mm, out
    assert "WR" in out["warnings_before_home"], out
    assert out["warnings_after_home"] == [], out
    assert out["busy"] is False, out
    return 0


def _version() -> str:
    from importlib.metadata import version

    return version("zaber-motion")


if __name__ == "__main__":
    sys.exit(main())
