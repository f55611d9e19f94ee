"""Plain file input and output for the tasks (no Prefect here).

Modules
-------
measured
    Measured FRFs, one module per format (``table``: CSV and Parquet, ``uff``:
    UFF58) around one internal form (``frf.MeasuredFRF``): ``read_measured``,
    ``write_measured``, ``MeasuredFRF`` and ``MeasuredDataError``;
    ``python -m tasks.io.measured PATH`` validates a file from the command line.

Import from the package itself (``from tasks.io.measured import
read_measured``); this package re-exports nothing.
"""
