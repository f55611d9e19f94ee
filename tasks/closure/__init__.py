"""Prefect tasks of the closure (``flows.diagnose``): residual, screening, checks, decision.

* :mod:`.store`: the closure's folder (steps of checksummed Parquet tables) and the conversions of its
  tables to fits and candidates;
* :mod:`.steps`: the settings, the effect library and the four tasks (baseline, screen, check, decide);
* :mod:`.summary`: ``closure.json`` and the candidates' table;
* :mod:`.intervals`: the 95 % intervals of the extended model for ``closure.json``;
* :mod:`.plot`: the residual maps before and after (``residuals.png``).

Everything goes under ``<run folder>/closure/`` (or another name), one
sub-folder per step with Parquet tables written atomically and a
``_step.json`` record of their SHA-256, as in :mod:`tasks.runstore`::

    closure/settings.json
    closure/step=baseline/baseline.parquet, residual_before.parquet
    closure/step=screen/screen.parquet
    closure/step=check/check=000.parquet ...     one per candidate, as it finishes
    closure/step=check/checks.parquet
    closure/step=decide/candidates.parquet, residual_after.parquet
    closure/residual_before.parquet, residual_after.parquet   (frequency_hz, sensor, residual)
    closure/closure.json, closure/residuals.png

A finished step is read back, not recomputed; a killed check stage keeps the
candidates already fitted. Each task wraps plain calls of :mod:`fe_core.closure.fits`,
:mod:`fe_core.closure.screening` and :mod:`fe_core.closure.decisions`.
"""
