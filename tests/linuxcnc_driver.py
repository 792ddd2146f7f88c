#!/usr/bin/python3
"""Drive a running LinuxCNC through its Python module ``linuxcnc`` (run by Debian's
/usr/bin/python3, which has the module; not by the project's Python).

Usage: ``linuxcnc_driver.py REQUEST.json RESULT.json``. The request holds ``joints`` (the
count), ``poses`` (world coordinates to command with MDI ``G53 G0``), ``jogs`` (``[joint,
increment]`` joint jogs after the poses, in joint mode) and ``pins`` (HAL pins to read at
each stop). It waits for LinuxCNC's task, resets the estop, switches the machine on, homes
all joints, commands each pose and, once the joints' feedback equals their command, records
``joint_actual_position``, ``actual_position`` and the pins; then the jogs, recording the same
once each jog has stopped. The result also holds LinuxCNC's error messages. Exit 0 when every
step completed, 1 otherwise (the result says which step failed).
"""

import json
import subprocess
import sys
import time

import linuxcnc

TIMEOUT = 20.0


def main(request_path, result_path):
    request = json.load(open(request_path))
    n = int(request["joints"])
    out = {"poses": [], "jogs": [], "errors": [], "failed": None}
    t0 = time.monotonic()
    # LinuxCNC's server, task and tool table up: asked in a fresh process each time (a stat
    # made before they are up fails for good in its process)
    probe = ("import linuxcnc; s = linuxcnc.stat(); s.poll(); "
             f"raise SystemExit(0 if s.task_state == linuxcnc.STATE_ESTOP and s.joints == {n} "
             "else 3)")
    def up():
        p = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True)
        return p.returncode == 0 and "not available" not in p.stdout + p.stderr

    while not up():
        if time.monotonic() - t0 > TIMEOUT:
            out["failed"] = "LinuxCNC did not come up"
            json.dump(out, open(result_path, "w"))
            return 1
        time.sleep(0.1)
    stat = linuxcnc.stat()
    cmd = linuxcnc.command()
    err = linuxcnc.error_channel()

    def poll():
        stat.poll()
        while True:
            e = err.poll()
            if not e:
                break
            out["errors"].append(e[1])

    def wait(cond, what, timeout=TIMEOUT):
        t0 = time.monotonic()
        while time.monotonic() - t0 < timeout:
            poll()
            if cond():
                return
            time.sleep(0.005)
        raise RuntimeError(f"timed out: {what}")

    reader = []

    def pins():
        if not request.get("pins"):
            return {}
        import hal

        if not reader:                    # hal.get_value needs a component of this process
            reader.append(hal.component("pkmcal-driver"))
            reader[0].ready()
        return {p: hal.get_value(p) for p in request["pins"]}

    def settled(joints=None):
        """The commanded joints have stopped and the feedback equals them (to the rounding of
        a HAL scale pair on the way: 1e-12 of the value)."""
        cmd_now = list(stat.joint_position[:n])
        fb = list(stat.joint_actual_position[:n])
        same = all(abs(a - b) <= 1e-12 * max(1.0, abs(b)) for a, b in zip(fb, cmd_now, strict=True))
        still = settled.last == cmd_now
        settled.last = cmd_now
        return same and still and all(j["inpos"] for j in stat.joint[:n])

    settled.last = None

    def record():
        return {"joints": list(stat.joint_actual_position[:n]),
                "commanded": list(stat.joint_position[:n]),
                "world": list(stat.actual_position[:6]), "pins": pins()}

    try:
        t0 = time.monotonic()
        while True:                       # the task and motion up: estop reset takes effect
            try:
                poll()
                cmd.state(linuxcnc.STATE_ESTOP_RESET)
                cmd.state(linuxcnc.STATE_ON)
                wait(lambda: stat.task_state == linuxcnc.STATE_ON, "machine on", 1.0)
                break
            except (linuxcnc.error, RuntimeError):
                if time.monotonic() - t0 > TIMEOUT:
                    raise RuntimeError("LinuxCNC did not come up (estop reset, machine "
                                       "on)") from None
                time.sleep(0.1)
        cmd.mode(linuxcnc.MODE_MANUAL)
        cmd.wait_complete()
        cmd.home(-1)
        cmd.wait_complete()
        wait(lambda: all(stat.homed[:n]), "homing")
        wait(lambda: all(j["inpos"] for j in stat.joint[:n]), "the move to HOME")
        out["homed"] = record()
        cmd.mode(linuxcnc.MODE_MDI)
        cmd.wait_complete()
        for pose in request["poses"]:
            words = " ".join(f"{c}{v:.12f}" for c, v in zip(request["axes"], pose, strict=True))
            cmd.mdi(f"G90 G53 G0 {words}")
            cmd.wait_complete(TIMEOUT)
            wait(lambda: stat.interp_state == linuxcnc.INTERP_IDLE and stat.inpos
                 and settled(), f"G0 {words}")
            out["poses"].append(record())
        if request.get("jogs"):
            cmd.mode(linuxcnc.MODE_MANUAL)
            cmd.wait_complete()
            cmd.teleop_enable(0)
            cmd.wait_complete()
            wait(lambda: stat.motion_mode == linuxcnc.TRAJ_MODE_FREE, "joint mode")
            for joint, increment in request["jogs"]:
                start = stat.joint_actual_position[joint]
                cmd.jog(linuxcnc.JOG_INCREMENT, True, joint, request.get("jog_speed", 10.0),
                        increment)
                def arrived(joint=joint, start=start, increment=increment):
                    return (abs(stat.joint_actual_position[joint] - start - increment)
                            < 1e-4 * max(1.0, abs(increment)))

                wait(arrived, f"jog of joint {joint}")
                wait(settled, f"jog of joint {joint} stopping")
                time.sleep(0.05)          # the world position of the stopped joints
                poll()
                out["jogs"].append(record())
    except Exception as exc:              # the test reads the failure from the result
        out["failed"] = f"{type(exc).__name__}: {exc}"
    finally:
        poll()
        json.dump(out, open(result_path, "w"))
    return 0 if out["failed"] is None else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1], sys.argv[2]))
