"""Data generators: each writes the files of ``data/`` it names (measured data from an independent model or a
finer mesh, example model files), so ``benchmarks/`` itself holds measurements. Run them as
``python -m benchmarks.make.<name>``; the data they wrote are committed, so nothing needs them to run."""
