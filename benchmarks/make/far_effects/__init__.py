"""Far-effect cases (issue 40): a tet10 plate with a hole and a rib (gmsh; data from scikit-fem's P2 assembly) and
a CalculiX S8R box arm with a B32 rib and a spring mount (data from ccx's matrices of a 2x finer deck), with the
factors far from nominal and an undeclared effect, lines 1-750 Hz at 1 Hz, noise with a floor.

    python -m benchmarks.make.far_effects                       # every case into runs/far_effects/<case>/
    python -m benchmarks.make.far_effects plate-mass-4 box-mass-3

The cases (which are for development and which are the check) are fixed in :mod:`.cases`; the structures in
:mod:`.plate` and :mod:`.shell`; the noise in :mod:`.noise`; writing a case in :mod:`.make`. Meshes and data are
generated, not committed (the plate's mesh is 0.5 MB, its data 0.4 MB a case).
"""
