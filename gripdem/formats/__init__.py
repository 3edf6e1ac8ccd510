"""Foreign formats in and out: the importers of the authors' Fordatis archives and of LAMMPS /
LIGGGHTS text dumps (with the Lees-Edwards settings inferred from the data and checked), and the
exporters for the tools the field uses: extended XYZ for OVITO, ParaView and ASE, LAMMPS dumps
and data files for handing a (predicted) state back to a DEM engine. Importers produce a
:class:`gripdem.data.schema.TrajectoryData`; nothing here trains or evaluates.
"""
