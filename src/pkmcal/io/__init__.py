"""File input and output: machine files (YAML), data files (CSV), atomic writes (SPEC 6)."""

from .atomic import atomic_write_text
from .csv_io import (
    read_constraint_link,
    read_joints,
    read_passive,
    read_poses,
    read_table,
    write_joints,
    write_poses,
    write_table,
)
from .machine_file import (
    MACHINE_FORMATS,
    MachineFormat,
    load_machine,
    machine_to_text,
    parse_machine,
    save_machine,
)

__all__ = [
    "MACHINE_FORMATS", "MachineFormat", "atomic_write_text", "load_machine", "machine_to_text",
    "parse_machine", "read_constraint_link", "read_joints", "read_passive", "read_poses",
    "read_table", "save_machine", "write_joints", "write_poses", "write_table",
]
