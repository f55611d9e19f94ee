"""The run report: read a run folder's Parquet/JSON, draw the paper's figures, write one HTML page.

Modules (plain functions; the Prefect flow is :mod:`flows.report`):

``data``      the run folder as DataFrames (:func:`~tasks.report.data.load_run`, repeats, polish, closure)
``frf``       dense FRF curves of a few parameter vectors, cached as Parquet
``figures``   one function per figure, DataFrames in, PNG out (matplotlib, Agg), one module per subject
``sections``  figures and tables of each report section
``html``      the self-contained page (PNG files embedded, and linked by name)
"""
