"""The report's figures: plain functions from DataFrames to PNG files (matplotlib, Agg).

Each function draws one figure of Zhou & Tang (numbers in the docstrings),
writes it to ``path`` and returns the path. No pyplot state is used (each
figure is its own :class:`matplotlib.figure.Figure`), so they can run in any
thread or process without a display.

One module per subject, sharing :mod:`._style` (sizes, colours, line styles, saving):

* :mod:`.frf`: FRF amplitudes (Figure 3) and relative residual maps;
* :mod:`.errors`: errors per iteration (Figures 4, 5) and the MRGP training time (Figure 9);
* :mod:`.parameters`: samples, parameters and sampling distributions per iteration (Figures 6-8);
* :mod:`.repeats`: repeated runs (Figures 10-13);
* :mod:`.closure`: the closure's FRF and its ranked candidate effects;
* :mod:`.correlation`: correlation and identifiability (Figures 14-19);
* :mod:`.intervals`: marginal posteriors, 95 % intervals and correlations of the estimates.
"""

import matplotlib

matplotlib.use("Agg")  # headless; must precede any pyplot import anywhere in the process
