"""File input and output: machine files (YAML), data files (CSV), atomic writes (SPEC 6)."""

from .atomic import atomic_write_text
from .csv_io import (
    joint_quantity,
    machine_readings,
    read_constraint_link,
    read_declared,
    read_distances,
    read_full_pose,
    read_groups,
    read_joints,
    read_passive,
    read_points,
    read_poses,
    read_positions,
    read_probe,
    read_readings,
    read_table,
    read_tracker,
    write_constraint_link,
    write_full_pose,
    write_instrument,
    write_joints,
    write_poses,
    write_positions,
    write_readings,
    write_table,
    write_tracker,
)
from .machine_file import (
    MACHINE_FORMATS,
    MachineFormat,
    bed_frame,
    load_machine,
    load_machine_file,
    machine_to_text,
    parse_machine,
    parse_machine_file,
    save_machine,
)


def read_measurements(instrument, path, machine, setups=None):
    """An instrument's measurements from a CSV file, by the reader it names.

    Parameters
    ----------
    instrument : Instrument
        A registry entry (:mod:`pkmcal.instruments.registry`); its ``reader`` names the
        function of this package that reads its files, else its declared columns are read
        (:func:`~pkmcal.io.csv_io.read_declared`).
    path : str or os.PathLike
        The data file.
    machine : Machine
        The machine (joint units, reading columns).
    setups : Setups or mapping, optional
        The experiment's set-ups: an instrument that numbers its rows by a group column
        refuses a file without it where its set-up holds several groups (None: no check).

    Returns
    -------
    object
        The instrument's data.

    Raises
    ------
    InputError
        Naming the file, row and column of what cannot be read.
    """
    if not instrument.reader:
        return read_declared(instrument, path, machine)
    if instrument.group_column is not None:
        return globals()[instrument.reader](path, machine, setups=setups)
    return globals()[instrument.reader](path, machine)


def write_measurements(instrument, path, data, machine, length_unit: str = "mm"):
    """Write an instrument's measurements to a CSV file, by the writer it names (the file its
    reader reads back).

    Parameters
    ----------
    instrument : Instrument
        A registry entry (:mod:`pkmcal.instruments.registry`); its ``writer`` names the
        function of this package that writes its data.
    path : str or os.PathLike
        Output file.
    data : object
        The instrument's data.
    machine : Machine
        The machine (joint units).
    length_unit : str, optional
        Column unit of lengths.

    Returns
    -------
    pathlib.Path
        The path written.
    """
    return globals()[instrument.writer](path, data, machine, length_unit)


__all__ = [
    "read_measurements", "write_measurements", "write_constraint_link", "MACHINE_FORMATS",
    "MachineFormat", "atomic_write_text",
    "joint_quantity", "load_machine", "load_machine_file", "parse_machine_file", "bed_frame",
    "machine_to_text", "parse_machine", "read_constraint_link", "read_full_pose", "read_joints",
    "read_passive", "read_poses", "read_positions", "read_readings", "read_table",
    "read_tracker", "save_machine", "write_full_pose", "write_joints", "write_poses",
    "write_positions", "write_readings", "write_table", "write_tracker", "machine_readings",
    "read_distances", "read_groups", "read_declared", "read_points", "read_probe",
    "write_instrument",
]
