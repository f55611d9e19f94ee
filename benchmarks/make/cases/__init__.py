"""Issue 40's held-out cases: updating cases drawn from seeds on structures made outside ``fe_core``.

    python -m benchmarks.make.cases --structures            # the structures' model files (data/cases/held_out/structures/)
    python -m benchmarks.make.cases --set dev               # the development set's measured data and truths
    python -m benchmarks.make.cases --set heldout --only ho20

Each case is a model the tool reads (``model.toml``: 6 segments, supports, 8 sensors, one hammer; 6-28k DOFs)
and a measurement made from a different discretisation (scikit-fem's P2 on a gmsh mesh of half the tool's
element size, scikit-fem's Q2 on the frame's hexahedra, ccx's matrices of a deck twice as fine), with the
segments' factors drawn in [-0.3, 0.3], one effect (a point mass, a mount, a damaged patch; a mass layer or a
flexible joint outside the tool's library) or none, lines from 0 Hz across 6-10 modes at 0.5 or 1 Hz, and the
noise of an impact test (H1 and coherence of simulated hits: relative response noise, a sensor floor, force
noise, fewer averages on some channels). ``truth.json`` holds what was drawn and made. docs/results/held-out.md says
how, lists the sets and holds the development set's table (``python -m benchmarks.heldout``).

Modules: :mod:`.sets` (ids, kinds, seeds), :mod:`.solids` (geometry and meshes), :mod:`.deck` (the shell deck),
:mod:`.modelfile` (the tool's model files), :mod:`.fem_data` (scikit-fem's assembly and the modal FRF),
:mod:`.effects` (the effects in the data's model), :mod:`.noise` (the test and the file), :mod:`.case` (draws
and effect places), :mod:`.build` (structures and cases).
"""
