"""LAMMPS / LIGGGHTS: text dumps read (:mod:`.dump`, :mod:`.series`), a tilted box's
Lees-Edwards settings (:mod:`.tilt`), the import into gripdem's conventions (:mod:`.importer`)
and dumps written (:mod:`.write`)."""

from gripdem.formats.lammps.importer import LammpsReport, read_lammps

__all__ = ["LammpsReport", "read_lammps"]
