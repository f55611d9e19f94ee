"""The large example (issue 41): a ribbed steel panel at any size, its measurement from an independent assembly.

    python -m benchmarks.make.large --dofs 150000     # data/examples/large/150k/ (also 500000, 1000000)
    python -m benchmarks.make.large --dofs 500000 --point-mass 0.03 --out runs/large/500k-mass   # the closure's case

writes, into a folder that git ignores (meshes of 10-50 MB are not committed):

* ``panel.msh``: the panel (:mod:`.geometry`: a plate with two long ribs and a cross rib, bolted at four
  corner holes, two lightening holes; 9 segments) meshed in tet10 by gmsh at about that many free DOFs;
* ``model.toml``: a copy of the committed template ``data/examples/large/model.toml`` (materials, damping,
  segments, supports, the 12 sensors and the hammer), which is also what the generator reads;
* ``measured.csv``: the receptance of every sensor to the hammer, complex, at :data:`N_LINES` lines from
  :data:`F_START` Hz every :data:`F_STEP` Hz, with :data:`NOISE` multiplicative complex Gaussian noise;
* ``truth.json``: the true factors, how they were drawn, the band, the modes kept, the remainder's share;
* ``generation.json``: DOFs, cells, the wall time and peak memory of each stage.

The measurement is not ``fe_core``'s: the model file is assembled by scikit-fem (:mod:`.assembly`) with the
true factors, and its FRF summed from its lowest modes plus the deflated remainder (:mod:`.synthesis`).
Everything is deterministic: gmsh on one thread with fixed options, ARPACK's start vector and the noise
seeded (``tests/examples/test_large_example.py`` checks it, and checks the data against ``fe_core``'s model
and against a direct solve on a small mesh).
"""

from pathlib import Path

#: The committed model file every size shares (its mesh is ``panel.msh`` beside it).
TEMPLATE = Path(__file__).resolve().parents[3] / "data" / "examples" / "large" / "model.toml"
#: Where ``--dofs N`` writes by default: ``<OUT>/<N / 1000>k/``.
OUT = TEMPLATE.parent
#: The measured lines, Hz: ``F_START + F_STEP * k`` for k < N_LINES (150-1794.5 Hz, the first 13 modes).
F_START, F_STEP, N_LINES = 150.0, 5.5, 300
#: Modes are kept up to this many times the band's top; the rest is the remainder.
CUTOFF_FACTOR = 1.75
#: Relative noise: each value times ``1 + NOISE (n1 + i n2) / sqrt(2)``, n1, n2 standard normal.
NOISE = 0.01
NOISE_SEED = 41
#: The true factors: uniform in ``ALPHA_RANGE`` (seed ``TRUTH_SEED``), rounded to 0.001; the same at every size.
ALPHA_RANGE = (-0.25, 0.10)
TRUTH_SEED = 4141
#: Where ``--point-mass`` puts the undeclared mass, m: on the plate's top face between the ribs' back half and
#: the sensors plate_4z and plate_5z (the nearest node of the mesh).
MASS_AT = (0.25, 0.31, 0.012)
